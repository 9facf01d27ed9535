//! Scene description: camera, body, Sun and poses.
