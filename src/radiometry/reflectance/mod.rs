//! Reflection models (BRDFs) named in scene files.
//! TEMPORARY: Lambert only until the reflectance branch lands.
use crate::error::Result;
use crate::radiometry::ScatteringGeometry;
use serde::{Deserialize, Serialize};

#[derive(Deserialize, Serialize, Clone, Debug)]
#[serde(tag = "model", rename_all = "snake_case")]
pub enum ReflectanceConfig {
    Lambert { albedo: f64 },
}
impl ReflectanceConfig {
    pub fn build(&self) -> Result<Reflectance> {
        match self {
            ReflectanceConfig::Lambert { albedo } => Ok(Reflectance::Lambert(*albedo)),
        }
    }
}
#[derive(Clone, Debug)]
pub enum Reflectance {
    Lambert(f64),
}
impl Reflectance {
    pub fn radiance_factor(&self, g: &ScatteringGeometry, albedo: f64) -> f64 {
        if g.mu0 <= 0.0 || g.mu <= 0.0 {
            0.0
        } else {
            albedo / std::f64::consts::PI * g.mu0
        }
    }
    pub fn albedo(&self) -> f64 {
        match self {
            Reflectance::Lambert(a) => *a,
        }
    }
    pub fn is_spectrally_flat(&self) -> bool {
        true
    }
    pub fn albedo_at(&self, _w: f64) -> f64 {
        self.albedo()
    }
    pub fn name(&self) -> &'static str {
        "lambert"
    }
}
