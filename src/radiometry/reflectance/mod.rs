//! Reflection models (BRDFs) named in scene files.
//! TEMPORARY: replaced by the reflectance branch.
use crate::error::Result;
use crate::radiometry::ScatteringGeometry;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

#[derive(Deserialize, Serialize, Clone, Debug)]
#[serde(tag = "model", rename_all = "snake_case")]
pub enum ReflectanceConfig {
    Lambert { albedo: f64 },
    Area { albedo: f64 },
    LommelSeeliger { albedo: f64 },
}
impl ReflectanceConfig {
    pub fn build(&self) -> Result<Reflectance> {
        Ok(match self {
            ReflectanceConfig::Lambert { albedo } => Reflectance::Lambert(*albedo),
            ReflectanceConfig::Area { albedo } => Reflectance::Area(*albedo),
            ReflectanceConfig::LommelSeeliger { albedo } => Reflectance::Ls(*albedo),
        })
    }
}
#[derive(Clone, Debug)]
pub enum Reflectance {
    Lambert(f64),
    Area(f64),
    Ls(f64),
}
impl Reflectance {
    pub fn radiance_factor(&self, g: &ScatteringGeometry, albedo: f64) -> f64 {
        if g.mu0 <= 0.0 || g.mu <= 0.0 {
            return 0.0;
        }
        match self {
            Reflectance::Lambert(_) => albedo / PI * g.mu0,
            Reflectance::Area(_) => albedo / (2.0 * PI),
            Reflectance::Ls(_) => 2.0 * albedo / PI * g.mu0 / (g.mu0 + g.mu),
        }
    }
    pub fn albedo(&self) -> f64 {
        match self {
            Reflectance::Lambert(a) | Reflectance::Area(a) | Reflectance::Ls(a) => *a,
        }
    }
    pub fn is_spectrally_flat(&self) -> bool {
        true
    }
    pub fn albedo_at(&self, _w: f64) -> f64 {
        self.albedo()
    }
    pub fn name(&self) -> &'static str {
        match self {
            Reflectance::Lambert(_) => "lambert",
            Reflectance::Area(_) => "area",
            Reflectance::Ls(_) => "lommel_seeliger",
        }
    }
}
