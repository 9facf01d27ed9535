//! Solar spectra, detector response tables and band integrals.
