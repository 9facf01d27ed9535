//! Reflection models (BRDFs) named in scene files.
