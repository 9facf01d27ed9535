//! The scene: what is out there and where. Camera (geometry and detector),
//! Sun spectrum, body (shape, reflectance, maps) and the poses of all three.
//!
//! [`Scene::from_file`] reads the TOML scene file documented in
//! `docs/SCENE.md`; unknown and missing keys are errors naming the key and
//! the file, and every value is checked before anything is rendered.

pub mod camera;
pub mod horizon;
pub mod maps;
pub mod relief_slopes;
pub mod surface;
pub mod tile_surface;
pub mod tiles;

use std::path::{Path, PathBuf};

use glam::{DQuat, DVec3};
use serde::Deserialize;

use crate::ephemeris::{self, Ephemeris, Spice};
use crate::error::{toml_message, Error, Result};
use crate::radiometry::reflectance::{MappedParameter, Reflectance, ReflectanceConfig};
use crate::radiometry::spectrum::{Response, SolarSpectrum, Table};
use crate::render_settings::RenderSettings;
use crate::sensor::{Readout, SensorFile, SensorParams};
pub use camera::Pinhole;
use camera::Psf;
pub use maps::{EquirectMap, NormalMap};

/// Camera: pinhole geometry plus the detector chain of the paper's Eq. 2.
#[derive(Clone, Debug)]
pub struct Camera {
    /// Projection geometry.
    pub pinhole: Pinhole,
    /// Pixel pitch [m].
    pub pixel_pitch: f64,
    /// Focal length [m].
    pub focal_length: f64,
    /// Focal ratio (focal length / aperture diameter).
    pub f_number: f64,
    /// Exposure time [s].
    pub exposure: f64,
    /// Full-well capacity [e⁻].
    pub full_well: f64,
    /// ADC bits.
    pub bits: u32,
    /// Gain [DN/e⁻].
    pub gain: f64,
    /// Waveband [m].
    pub band: [f64; 2],
    /// Quantum efficiency.
    pub quantum_efficiency: Response,
    /// Optical transmission.
    pub transmission: Response,
    /// The EMVA 1288 sensor chain (`[camera.sensor]`); None: the ideal
    /// detector of Eq. 2.
    pub sensor: Option<SensorParams>,
    /// The optics' point spread function (`camera.psf`), integrated over
    /// each pixel; None: the pinhole's ideal image.
    pub psf: Option<Psf>,
    /// Lens distortion (`camera.distortion`): the renderer draws the ideal
    /// image on `distortion.ideal` and resamples it onto `pinhole`'s grid.
    pub distortion: Option<crate::optics::distortion::Lens>,
    /// Which frame of the sensor's temporal noise a render draws (0 for a
    /// scene file; a dataset item's own noise seed, so items differ in
    /// their noise but share the camera's PRNU and DSNU).
    pub sensor_frame: u64,
}

impl Camera {
    /// The grid the renderer draws on: the ideal grid covering the
    /// distorted field with `camera.distortion`, else the camera's own.
    pub fn render_pinhole(&self) -> &Pinhole {
        self.distortion
            .as_ref()
            .map_or(&self.pinhole, |lens| &lens.ideal)
    }

    /// Full well, gain and bits: the readout the sensor chain ends in.
    pub fn readout(&self) -> Readout {
        Readout {
            full_well: self.full_well,
            gain: self.gain,
            bits: self.bits,
        }
    }

    /// Entrance pupil area [m²].
    pub fn pupil_area(&self) -> f64 {
        let d = self.focal_length / self.f_number;
        std::f64::consts::PI * d * d / 4.0
    }

    /// Largest DN the ADC outputs.
    pub fn max_dn(&self) -> f64 {
        (2f64.powi(self.bits as i32) - 1.0).max(1.0)
    }
}

/// Surface relief: displacement (height) and shading normals.
#[derive(Clone, Debug, Default)]
pub struct Relief {
    /// Height above the reference sphere [m], and its derivatives with
    /// respect to latitude and longitude [m/rad] (see [`surface`]).
    pub height: Option<(EquirectMap, EquirectMap, EquirectMap)>,
    /// Largest |height| [m] of `height` and `height_tiles` (0 without):
    /// how far the displacement can move the limb.
    pub height_bound: f64,
    /// DEM tiles over `height` (`[[body.dem_tiles]]` with `shadows.displace`):
    /// where they cover a point, its height and slopes are theirs.
    pub height_tiles: Option<std::sync::Arc<tile_surface::HeightTiles>>,
    /// Tangent-space shading normals.
    pub normals: Option<NormalMap>,
    /// Shadows cast by the relief of a DEM (`[body] shadows`), with the
    /// horizon maps of its DEM tiles (`[[body.dem_tiles]]`) layered over.
    pub shadows: Option<std::sync::Arc<horizon::ReliefShadows>>,
    /// Albedo tiles (`[[body.albedo_tiles]]`) over the albedo map (or the
    /// model's albedo): kept here, with the relief, so that a `Body` built
    /// elsewhere needs no new field.
    pub albedo_tiles: Option<std::sync::Arc<tiles::TileSet>>,
    /// Whether the displacement's terrain past the sphere's limb can rise
    /// into view (`shadows.far_limb`; `render::sight`).
    pub far_limb: bool,
}

impl Body {
    /// Whether the body's reflectance is the same at every wavelength (the
    /// paper's single-PF path): no λ table in the model, no albedo spectrum.
    pub fn is_spectrally_flat(&self) -> bool {
        self.reflectance.is_spectrally_flat() && self.albedo_spectrum.is_none()
    }

    /// The albedo factor s(λ) (1 without an albedo spectrum; the table's
    /// end values beyond its ends).
    pub fn albedo_factor(&self, wavelength_m: f64) -> f64 {
        match &self.albedo_spectrum {
            None => 1.0,
            Some(t) => {
                let w = &t.wavelengths;
                t.eval(wavelength_m.clamp(w[0], w[w.len() - 1]))
            }
        }
    }
}

/// A spherical body.
#[derive(Clone, Debug)]
pub struct Body {
    /// Reference radius [m].
    pub radius: f64,
    /// Reflection model.
    pub reflectance: Reflectance,
    /// Per-point value of the model's albedo parameter.
    pub albedo_map: Option<EquirectMap>,
    /// A spectral factor s(λ) on the albedo parameter (and on the map):
    /// albedo(x, λ) = map(x) · s(λ). None: no factor.
    pub albedo_spectrum: Option<Table>,
    /// Displacement and normal maps.
    pub relief: Relief,
    /// Per-point values of model parameters other than the albedo
    /// (`parameter_maps`), at most [`MAX_PARAMETER_MAPS`], each parameter once.
    pub parameter_maps: Vec<(MappedParameter, EquirectMap)>,
    /// The body stands for the real Moon: renders report their disk
    /// irradiance against LIME (`lime_reference`).
    pub lime_reference: bool,
}

/// Most `[body] parameter_maps` entries (one per parameter of the richest
/// model, Hapke's b, c, h_S and B_S0).
pub const MAX_PARAMETER_MAPS: usize = 4;

/// Poses of body, camera and Sun in the world (inertial) frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct State {
    /// Body centre [m].
    pub body_position: DVec3,
    /// Rotation of body-fixed vectors into the world frame.
    pub body_attitude: DQuat,
    /// Camera centre [m].
    pub camera_position: DVec3,
    /// Rotation of camera vectors (x right, y down, z boresight) into the
    /// world frame.
    pub camera_attitude: DQuat,
    /// Sun centre [m].
    pub sun_position: DVec3,
    /// A sphere that can shadow the body (e.g. the Earth in a lunar
    /// eclipse); the Sun is an extended disk, so penumbrae are graded.
    pub occulter: Option<Occulter>,
}

/// A sphere casting a shadow on the body.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Occulter {
    /// Centre [m], world frame.
    pub position: DVec3,
    /// Shadow-casting radius [m] (for the Earth, include the ~2 %
    /// enlargement of the umbra by the atmosphere if wanted).
    pub radius: f64,
}

impl State {
    /// Reject non-finite vectors, a camera inside the body and a Sun inside
    /// the body; `field` prefixes the names in the error.
    pub fn check(&self, radius: f64, field: &str) -> Result<()> {
        let vectors = [
            ("body_position", self.body_position),
            ("camera_position", self.camera_position),
            ("sun_position", self.sun_position),
        ];
        for (name, v) in vectors {
            if !v.is_finite() {
                return Err(Error::invalid(format!("{field}.{name}"), "not finite"));
            }
        }
        for (name, q) in [
            ("body_attitude", self.body_attitude),
            ("camera_attitude", self.camera_attitude),
        ] {
            if !q.is_finite() || (q.length() - 1.0).abs() > 1e-6 {
                return Err(Error::invalid(
                    format!("{field}.{name}"),
                    "not a finite unit quaternion",
                ));
            }
        }
        let camera_range = (self.camera_position - self.body_position).length();
        if camera_range <= radius {
            return Err(Error::invalid(
                format!("{field}.camera_position"),
                format!("camera is inside the body ({camera_range} m from its centre, radius {radius} m)"),
            ));
        }
        if let Some(o) = &self.occulter {
            if !(o.position.is_finite() && o.radius.is_finite() && o.radius > 0.0) {
                return Err(Error::invalid(
                    format!("{field}.occulter"),
                    "needs a finite position and a radius > 0",
                ));
            }
        }
        if (self.sun_position - self.body_position).length() <= radius {
            return Err(Error::invalid(
                format!("{field}.sun_position"),
                "Sun is inside the body",
            ));
        }
        Ok(())
    }
}

/// Scalar-first quaternion [w, x, y, z] to a unit rotation; rejects zero and
/// non-finite quaternions, naming `field`.
pub fn quaternion(wxyz: [f64; 4], field: &str) -> Result<DQuat> {
    if wxyz.iter().any(|v| !v.is_finite()) {
        return Err(Error::invalid(
            field,
            "quaternion has a non-finite component",
        ));
    }
    let q = DQuat::from_xyzw(wxyz[1], wxyz[2], wxyz[3], wxyz[0]);
    let norm = q.length();
    if norm < 1e-9 {
        return Err(Error::invalid(field, "quaternion has zero norm"));
    }
    Ok(q / norm)
}

/// A complete scene.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Camera.
    pub camera: Camera,
    /// Solar spectrum at 1 au.
    pub sun: SolarSpectrum,
    /// The body.
    pub body: Body,
    /// Poses.
    pub state: State,
    /// Sampling settings.
    pub render: RenderSettings,
    /// The stars behind the body (`[stars]`); None: a black sky.
    pub stars: Option<crate::stars::StarField>,
}

// ---------------------------------------------------------------- TOML file

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    camera: CameraFile,
    sun: SunFile,
    body: BodyFile,
    state: StateFile,
    ephemeris: Option<EphemerisFile>,
    #[serde(default)]
    render: RenderSettings,
    stars: Option<crate::stars::StarsFile>,
}

/// `[camera]` table of a scene file.
#[derive(Deserialize, Clone, Debug)]
#[serde(deny_unknown_fields)]
pub struct CameraFile {
    resolution: [usize; 2],
    pixel_pitch: f64,
    focal_length: Option<f64>,
    fov_deg: Option<f64>,
    principal_point: Option<[f64; 2]>,
    f_number: f64,
    exposure: f64,
    full_well: f64,
    bits: u32,
    #[serde(default)]
    gain: f64,
    band: [f64; 2],
    #[serde(default = "unit_response")]
    quantum_efficiency: ResponseFile,
    #[serde(default = "unit_response")]
    transmission: ResponseFile,
    sensor: Option<SensorFile>,
    psf: Option<PsfFile>,
    /// Brown–Conrady distortion: an intrinsics file of the geometric
    /// calibration's format (`instruments::intrinsics`).
    distortion: Option<PathBuf>,
    distortion_supersample: Option<usize>,
}

/// `camera.psf`: the optics' point spread function.
#[derive(Deserialize, Clone, Debug)]
#[serde(tag = "model", rename_all = "snake_case", deny_unknown_fields)]
enum PsfFile {
    /// `{ model = "gaussian", sigma_px = 0.8 }`.
    Gaussian { sigma_px: f64 },
    /// `{ model = "airy", wavelength = 6.5e-7 }`: diffraction at the
    /// camera's f-number on its pixel pitch.
    Airy { wavelength: f64 },
}

#[derive(Deserialize, Clone, Debug)]
#[serde(untagged)]
enum ResponseFile {
    Constant(f64),
    Table(PathBuf),
    Normalised(NormalisedTable),
}

/// `{ path = "...", normalisation = "photon" | "energy" }`.
#[derive(Deserialize, Clone, Debug)]
#[serde(deny_unknown_fields)]
struct NormalisedTable {
    path: PathBuf,
    normalisation: Normalisation,
}

/// What a response table's values count.
#[derive(Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
enum Normalisation {
    /// Electrons per photon (a quantum efficiency) or a transmitted fraction.
    Photon,
    /// A responsivity in A/W (electrons per joule × e).
    Energy,
}

fn unit_response() -> ResponseFile {
    ResponseFile::Constant(1.0)
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SunFile {
    spectrum: String,
    temperature: Option<f64>,
    irradiance_1au: Option<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct BodyFile {
    radius: f64,
    reflectance: ReflectanceConfig,
    albedo_map: Option<AlbedoMapFile>,
    albedo_spectrum: Option<Vec<[f64; 2]>>,
    displacement_map: Option<DisplacementMapFile>,
    normal_map: Option<NormalMapFile>,
    shadows: Option<ShadowsSpec>,
    dem_tiles: Option<Vec<tiles::DemTileFile>>,
    albedo_tiles: Option<Vec<tiles::AlbedoTileFile>>,
    /// Largest |height| [m] of a DEM tile (default 25 km).
    max_abs_height: Option<f64>,
    parameter_maps: Option<Vec<ParameterMapFile>>,
    #[serde(default)]
    lime_reference: bool,
}

/// A map of one model parameter: its values stretched as an albedo map's.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ParameterMapFile {
    parameter: String,
    path: PathBuf,
    min: f64,
    max: f64,
    #[serde(default = "unit_power")]
    power: f64,
    #[serde(default)]
    encoding: MapEncoding,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct AlbedoMapFile {
    path: PathBuf,
    min: f64,
    max: f64,
    /// Power on the normalised map before the stretch (1: linear).
    #[serde(default = "unit_power")]
    power: f64,
    #[serde(default)]
    encoding: MapEncoding,
    /// Coefficients of a smooth factor exp(p(n)) applied after the
    /// stretch ([`EquirectMap::modulate_large_scale`]).
    large_scale: Option<[f64; 8]>,
}

fn unit_power() -> f64 {
    1.0
}

/// Range of `albedo_map.power`: wide enough for any contrast law, narrow
/// enough that t^power stays representable in f32 for every map value.
const MAP_POWER_RANGE: (f64, f64) = (0.1, 10.0);

/// Largest |coefficient| of `albedo_map.large_scale`: the basis functions
/// are bounded by 1 (four) and ½ (four), so |p(n)| ≤ 6 × 2 and the factor
/// stays within e^±12, finite and positive in f32.
const LARGE_SCALE_MAX: f64 = 2.0;

/// How an albedo map's 8/16-bit values encode light.
#[derive(Deserialize, Clone, Copy, Debug, Default, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
enum MapEncoding {
    /// Values proportional to reflectance.
    #[default]
    Linear,
    /// A visual (sRGB-encoded) mosaic: decoded to linear light first.
    Srgb,
}

/// A scene whose `[body]` is a separate body file: `[body] file = "..."`.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFileBodyRef {
    camera: CameraFile,
    sun: SunFile,
    body: BodyRef,
    state: StateFile,
    ephemeris: Option<EphemerisFile>,
    #[serde(default)]
    render: RenderSettings,
    stars: Option<crate::stars::StarsFile>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct BodyRef {
    file: PathBuf,
    /// Relief for this scene over the body file's (paths against the
    /// scene's directory).
    shadows: Option<ShadowsSpec>,
}

/// A body file: its `[body]` table (relative paths in it resolve against
/// the body file's directory).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct BodyFileOnly {
    body: BodyFile,
}

/// Whether the `[body]` table of a scene names a body file.
#[derive(Deserialize)]
struct BodyProbe {
    body: Option<toml::Table>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DisplacementMapFile {
    path: PathBuf,
    scale: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct NormalMapFile {
    path: PathBuf,
}

/// `[body] shadows`: the DEM whose relief casts shadows and, with
/// `displace`, also moves the limb and tilts the shading normals (one DEM,
/// one bilinear interpolation for all three; docs/SCENE.md).
#[derive(Deserialize, serde::Serialize, Clone, Debug)]
#[serde(deny_unknown_fields)]
pub struct ShadowsSpec {
    /// Equirectangular DEM (relative paths against the scene's directory).
    pub dem: PathBuf,
    /// Factor from DEM values to metres.
    pub scale: f64,
    /// Azimuths of the horizon map.
    #[serde(default = "default_azimuths")]
    pub azimuths: i64,
    /// Where the horizon map is cached (default: [`horizon::default_cache_dir`]).
    pub cache_dir: Option<PathBuf>,
    /// When a frame applies the shadows.
    #[serde(default)]
    pub mode: horizon::ShadowMode,
    /// The DEM is also the displacement map: its heights move the limb and
    /// its slopes tilt the normals.
    #[serde(default)]
    pub displace: bool,
    /// With `displace`: terrain past the sphere's limb rises into view
    /// (default: on with `displace`; `true` without it is an error).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub far_limb: Option<bool>,
}

impl ShadowsSpec {
    /// The documented settings for `dem` (scale 1000: heights in km, as
    /// `data/maps/ldem_4.tif`), default azimuths and cache.
    pub fn km_dem(dem: impl Into<PathBuf>, mode: horizon::ShadowMode, displace: bool) -> Self {
        ShadowsSpec {
            dem: dem.into(),
            scale: 1000.0,
            azimuths: default_azimuths(),
            cache_dir: None,
            mode,
            displace,
            far_limb: None,
        }
    }
}

impl Relief {
    /// The relief `[body] shadows` builds: the horizon map of `spec`'s DEM
    /// (paths against `base`) and, with `displace`, the same DEM as the
    /// displacement. Errors name `body.shadows.<key>`.
    pub fn from_dem(spec: &ShadowsSpec, base: &Path, radius: f64) -> Result<Relief> {
        Self::from_dem_tiles(spec, &[], tiles::DEFAULT_MAX_ABS_HEIGHT, base, radius)
    }

    /// [`Relief::from_dem`] with DEM tiles whose horizon maps are layered
    /// over the global one; with `displace`, the tiles' heights and slopes
    /// are layered over the global DEM's displacement the same way.
    pub fn from_dem_tiles(
        spec: &ShadowsSpec,
        dem_tiles: &[tiles::DemTileFile],
        max_abs_height: f64,
        base: &Path,
        radius: f64,
    ) -> Result<Relief> {
        if spec.far_limb == Some(true) && !spec.displace {
            return Err(Error::invalid(
                "body.shadows.far_limb",
                "needs `displace = true` (the far limb is the displacement's)",
            ));
        }
        let (shadows, dem, tiles) = relief_shadows(spec, dem_tiles, max_abs_height, base, radius)?;
        let mut relief = Relief {
            shadows: Some(std::sync::Arc::new(shadows)),
            ..Relief::default()
        };
        if spec.displace {
            relief.far_limb = spec.far_limb.unwrap_or(true);
            relief.set_height(dem);
            if let Some(set) = tiles {
                relief.set_height_tiles(std::sync::Arc::new(set));
            }
        }
        Ok(relief)
    }

    /// Sets the displacement to `height` [m] (its slopes and bound with it).
    pub fn set_height(&mut self, height: EquirectMap) {
        let (lo, hi) = height.range();
        self.height_bound = (lo.abs().max(hi.abs())) as f64;
        let (d_lat, d_lon) = height.gradients();
        self.height = Some((height, d_lat, d_lon));
    }

    /// Layers DEM `tiles` (heights [m]) over the displacement set by
    /// [`Self::set_height`], widening its bound.
    pub fn set_height_tiles(&mut self, tiles: std::sync::Arc<tiles::TileSet>) {
        let t = tile_surface::HeightTiles::new(tiles);
        self.height_bound = self.height_bound.max(t.bound());
        self.height_tiles = Some(std::sync::Arc::new(t));
    }
}

fn default_azimuths() -> i64 {
    horizon::DEFAULT_AZIMUTHS as i64
}

/// The horizon map of `[body] shadows` with its DEM tiles' maps layered
/// over, from their caches or computed, the global DEM [m] and the tiles.
fn relief_shadows(
    s: &ShadowsSpec,
    dem_tiles: &[tiles::DemTileFile],
    max_abs_height: f64,
    base: &Path,
    radius: f64,
) -> Result<(horizon::ReliefShadows, EquirectMap, Option<tiles::TileSet>)> {
    let key = "body.shadows";
    if !(s.scale.is_finite() && s.scale > 0.0) {
        return Err(Error::invalid(
            format!("{key}.scale"),
            format!("need a finite value > 0, got {}", s.scale),
        ));
    }
    let (lo, hi) = horizon::AZIMUTH_RANGE;
    if !(lo as i64..=hi as i64).contains(&s.azimuths) {
        return Err(Error::invalid(
            format!("{key}.azimuths"),
            format!("need {lo} … {hi}, got {}", s.azimuths),
        ));
    }
    let azimuths = s.azimuths as usize;
    let path = resolve(base, &s.dem);
    let mut dem = load_map(base, &s.dem, &format!("{key}.dem"))?;
    dem.scale(s.scale);
    horizon::check_dem(&dem, azimuths, &path, key)?;
    let cache_dir = match &s.cache_dir {
        Some(d) => resolve(base, d),
        None => horizon::default_cache_dir(),
    };
    let params = horizon::HorizonParams {
        radius,
        scale: s.scale,
        azimuths,
    };
    let start = std::time::Instant::now();
    let (map, cache, cache_file) =
        horizon::HorizonMap::load_or_compute(&path, &dem, &params, &cache_dir)
            .map_err(|e| Error::invalid(format!("{key}.dem"), e.to_string()))?;
    let (h_min, h_max) = dem.range();
    let mut cell = radius * std::f64::consts::PI / dem.height as f64;
    let mut relief = (h_max - h_min) as f64;
    let mut slopes = relief_slopes::SlopeScales::of_global(&dem, radius);
    let mut map = map;
    let mut tile_set = None;
    if !dem_tiles.is_empty() {
        let key = "body.dem_tiles";
        let set = tiles::load_dem_tiles(dem_tiles, base, max_abs_height, key)?;
        let (overlay, _) = tiles::tile_horizons(&set, &path, &dem, &params, &cache_dir, key)?;
        for t in set.tiles() {
            let (lo, hi) = t.map.range();
            relief = relief.max((hi.max(h_max) - lo.min(h_min)) as f64);
            cell = cell.min(radius * t.grid.cell_lat());
            let g = &t.grid;
            slopes = slopes.with(relief_slopes::SlopeScales::of_map(
                &t.map,
                radius,
                g.lat_max,
                g.cell_lat(),
                g.cell_lon(),
            ));
        }
        map = map.with_overlay(overlay);
        tile_set = Some(set);
    }
    let shadows = horizon::ReliefShadows {
        map,
        mode: s.mode,
        cell,
        relief,
        slopes,
        cache,
        cache_file,
        seconds: start.elapsed().as_secs_f64(),
        dem_path: path,
        params,
    };
    Ok((shadows, dem, tile_set))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct StateFile {
    body_position: Option<[f64; 3]>,
    body_attitude: Option<[f64; 4]>,
    camera_position: Option<[f64; 3]>,
    camera_attitude: [f64; 4],
    sun_position: Option<[f64; 3]>,
    occulter: Option<Occulter>,
    /// Epoch text (UTC, or with a ` TDB` suffix): Sun and Moon attitude
    /// then come from the `[ephemeris]` kernels.
    epoch: Option<String>,
}

fn identity_quaternion() -> [f64; 4] {
    [1.0, 0.0, 0.0, 0.0]
}

/// A value that must be given, named in the error when it is not.
fn required<T>(v: Option<T>, field: &str) -> Result<T> {
    v.ok_or_else(|| Error::invalid(field, "required (no `state.epoch` given)"))
}

/// Poses from explicit positions: the path without an epoch.
fn explicit_state(s: &StateFile) -> Result<State> {
    Ok(State {
        body_position: vector(s.body_position.unwrap_or_default(), "state.body_position")?,
        body_attitude: quaternion(
            s.body_attitude.unwrap_or_else(identity_quaternion),
            "state.body_attitude",
        )?,
        camera_position: vector(
            required(s.camera_position, "state.camera_position")?,
            "state.camera_position",
        )?,
        camera_attitude: quaternion(s.camera_attitude, "state.camera_attitude")?,
        sun_position: vector(
            required(s.sun_position, "state.sun_position")?,
            "state.sun_position",
        )?,
        occulter: s.occulter,
    })
}

/// Poses at `state.epoch` from the kernels: world = J2000 axes with the
/// Moon at the origin, so the body (the Moon) sits at the origin with its
/// Mean Earth/polar-axis attitude and the Sun where the kernels put it.
fn epoch_state(
    s: &StateFile,
    epoch: &str,
    eph: Option<&EphemerisFile>,
    base: &Path,
) -> Result<State> {
    let eph = eph.ok_or_else(|| {
        Error::invalid(
            "ephemeris",
            "`state.epoch` needs an `[ephemeris]` table with `kernels`",
        )
    })?;
    for (given, key) in [
        (s.body_position.is_some(), "state.body_position"),
        (s.body_attitude.is_some(), "state.body_attitude"),
        (s.sun_position.is_some(), "state.sun_position"),
    ] {
        if given {
            return Err(Error::invalid(
                key,
                "not allowed with `state.epoch` (the kernels give it)",
            ));
        }
    }
    let t = ephemeris::parse_epoch(epoch, "state.epoch")?;
    if eph.kernels.is_empty() || eph.kernels.len() > 64 {
        return Err(Error::invalid(
            "ephemeris.kernels",
            "give 1 to 64 kernel files",
        ));
    }
    let paths: Vec<PathBuf> = eph.kernels.iter().map(|k| resolve(base, k)).collect();
    let spice = Spice::load(&paths)?;
    let at = |e: Error| Error::invalid("state.epoch", format!("`{epoch}`: {e}"));
    let camera_position = match (s.camera_position, eph.observer) {
        (Some(p), None) => vector(p, "state.camera_position")?,
        (None, Some(o)) => spice
            .position(o.spk_id, ephemeris::MOON, t)
            .map_err(|e| Error::invalid("ephemeris.observer", e.to_string()))?,
        _ => {
            return Err(Error::invalid(
                "state.camera_position",
                "give exactly one of `state.camera_position` and `ephemeris.observer`",
            ))
        }
    };
    let body = DQuat::from_mat3(&spice.moon_to_j2000(t).map_err(at)?).normalize();
    Ok(State {
        body_position: DVec3::ZERO,
        body_attitude: body,
        camera_position,
        camera_attitude: quaternion(s.camera_attitude, "state.camera_attitude")?,
        sun_position: spice.sun_from_moon(t).map_err(at)?,
        occulter: s.occulter,
    })
}

/// `[ephemeris]`: the kernels an epoch is evaluated with.
#[derive(Deserialize, Clone, Debug)]
#[serde(deny_unknown_fields)]
struct EphemerisFile {
    /// SPK (`.bsp`) and binary PCK (`.bpc`) files.
    kernels: Vec<PathBuf>,
    /// The camera position from an SPK instead of `state.camera_position`.
    observer: Option<ObserverFile>,
}

#[derive(Deserialize, Clone, Copy, Debug)]
#[serde(deny_unknown_fields)]
struct ObserverFile {
    /// NAIF id of the spacecraft (or body) carrying the camera.
    spk_id: i32,
}

fn positive(value: f64, field: &str) -> Result<f64> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(Error::invalid(
            field,
            format!("must be finite and > 0, got {value}"),
        ))
    }
}

/// `value` within [lo, hi] (a physical range: beyond it products overflow
/// or underflow into NaN long before any real instrument is described).
fn within(value: f64, lo: f64, hi: f64, field: &str) -> Result<f64> {
    if value.is_finite() && (lo..=hi).contains(&value) {
        Ok(value)
    } else {
        Err(Error::invalid(
            field,
            format!("must be within [{lo:e}, {hi:e}], got {value:e}"),
        ))
    }
}

fn vector(v: [f64; 3], field: &str) -> Result<DVec3> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(DVec3::from_array(v))
    } else {
        Err(Error::invalid(field, "has a non-finite component"))
    }
}

impl Scene {
    /// Read and check a scene file. Relative paths inside it resolve
    /// against the file's directory.
    pub fn from_file(path: &Path) -> Result<Self> {
        let text = crate::infile::read_text_bounded(path, crate::infile::CONFIG_LIMIT)?;
        Self::from_toml(&text, path)
    }

    /// Parse a scene from TOML text; `path` names the source in errors and
    /// anchors relative paths.
    pub fn from_toml(text: &str, path: &Path) -> Result<Self> {
        let to_parse = |e: Error| match e {
            Error::Invalid { .. } | Error::Other(_) => Error::parse(path, e.to_string()),
            other => other,
        };
        let base = path.parent().unwrap_or(Path::new("."));
        let probe: BodyProbe =
            toml::from_str(text).map_err(|e| Error::parse(path, toml_message(text, &e)))?;
        let names_file = probe.body.is_some_and(|b| b.contains_key("file"));
        if !names_file {
            let file: SceneFile =
                toml::from_str(text).map_err(|e| Error::parse(path, toml_message(text, &e)))?;
            return Self::build(file, base, base).map_err(to_parse);
        }
        let file: SceneFileBodyRef =
            toml::from_str(text).map_err(|e| Error::parse(path, toml_message(text, &e)))?;
        let body_path = resolve(base, &file.body.file);
        let body_text = crate::infile::read_text_bounded(&body_path, crate::infile::CONFIG_LIMIT)?;
        let body: BodyFileOnly = toml::from_str(&body_text)
            .map_err(|e| Error::parse(&body_path, toml_message(&body_text, &e)))?;
        let body_base = body_path.parent().unwrap_or(Path::new("."));
        let mut body = body.body;
        if let Some(mut spec) = file.body.shadows {
            if body.shadows.is_some() {
                return Err(Error::parse(
                    path,
                    format!("`body.shadows`: {} has its own", body_path.display()),
                ));
            }
            // The scene's relief: its paths are the scene's.
            let absolute =
                |p: &Path| std::path::absolute(resolve(base, p)).map_err(|e| Error::io(p, e));
            spec.dem = absolute(&spec.dem)?;
            spec.cache_dir = spec.cache_dir.as_deref().map(absolute).transpose()?;
            body.shadows = Some(spec);
        }
        let scene = SceneFile {
            camera: file.camera,
            sun: file.sun,
            body,
            state: file.state,
            ephemeris: file.ephemeris,
            render: file.render,
            stars: file.stars,
        };
        Self::build(scene, base, body_base).map_err(|e| match e {
            Error::Invalid { ref field, .. } if field.starts_with("body") => {
                Error::parse(&body_path, e.to_string())
            }
            other => to_parse(other),
        })
    }

    /// `base` anchors the scene's relative paths, `body_base` the body's.
    fn build(file: SceneFile, base: &Path, body_base: &Path) -> Result<Self> {
        let camera = camera_from(&file.camera, base)?;
        let sun = match file.sun.spectrum.as_str() {
            "blackbody" => SolarSpectrum::blackbody(
                file.sun
                    .temperature
                    .ok_or_else(|| Error::invalid("sun.temperature", "required for a blackbody"))?,
                file.sun.irradiance_1au.unwrap_or(1361.0),
            )?,
            table => {
                SolarSpectrum::from_csv(&resolve(base, Path::new(table)), file.sun.irradiance_1au)
                    .map_err(|e| Error::invalid("sun.spectrum", e.to_string()))?
            }
        };
        let body = body_from(&file.body, body_base)?;
        let radius = body.radius;
        let s = &file.state;
        let state = match &s.epoch {
            Some(epoch) => epoch_state(s, epoch, file.ephemeris.as_ref(), base)?,
            None if file.ephemeris.is_some() => {
                return Err(Error::invalid("ephemeris", "given without `state.epoch`"))
            }
            None => explicit_state(s)?,
        };
        state.check(radius, "state")?;
        file.render.check()?;
        // The exact filter's table is built now rather than in the first
        // frame; with the map samples it is never built (16.8 MB for 2k).
        if file.render.map_filter != crate::render_settings::MapFilter::Samples {
            if let Some(map) = &body.albedo_map {
                map.prepare_filters();
            }
        }
        let stars = file
            .stars
            .as_ref()
            .map(|f| crate::stars::StarField::from_file(f, base, s.epoch.as_deref()))
            .transpose()?;
        Ok(Scene {
            camera,
            sun,
            body,
            state,
            render: file.render,
            stars,
        })
    }
}

/// Build a body from its `[body]` table; `body_base` anchors its paths.
fn body_from(body: &BodyFile, body_base: &Path) -> Result<Body> {
    let radius = positive(body.radius, "body.radius")?;
    let reflectance = body.reflectance.build()?;
    let albedo_map = match &body.albedo_map {
        Some(m) => {
            let spec = MapSpec {
                path: &m.path,
                min: m.min,
                max: m.max,
                power: m.power,
                encoding: m.encoding,
                nonneg: true,
            };
            let mut map = spec.load(body_base, "body.albedo_map")?;
            if let Some(c) = &m.large_scale {
                if let Some(k) = c.iter().position(|v| !(v.abs() <= LARGE_SCALE_MAX)) {
                    return Err(Error::invalid(
                        "body.albedo_map.large_scale",
                        format!(
                            "need |coefficient| <= {LARGE_SCALE_MAX}, got {} at {k}",
                            c[k]
                        ),
                    ));
                }
                map.modulate_large_scale(c);
            }
            Some(map)
        }
        None => None,
    };
    let parameter_maps = parameter_maps(body, &reflectance, body_base)?;
    let albedo_spectrum = match &body.albedo_spectrum {
        Some(rows) => Some(Table::new(
            rows.iter().map(|r| r[0] * 1e-9).collect(),
            rows.iter().map(|r| r[1]).collect(),
            "body.albedo_spectrum",
        )?),
        None => None,
    };
    let max_abs_height = match body.max_abs_height {
        None => tiles::DEFAULT_MAX_ABS_HEIGHT,
        Some(v) => within(
            v,
            tiles::MAX_ABS_HEIGHT_RANGE.0,
            tiles::MAX_ABS_HEIGHT_RANGE.1,
            "body.max_abs_height",
        )?,
    };
    let dem_tiles = body.dem_tiles.as_deref().unwrap_or_default();
    if !dem_tiles.is_empty() && body.shadows.is_none() {
        return Err(Error::invalid(
            "body.dem_tiles",
            "DEM tiles are layered over the global DEM of `body.shadows`: give it",
        ));
    }
    let mut relief = match &body.shadows {
        Some(s) => Relief::from_dem_tiles(s, dem_tiles, max_abs_height, body_base, radius)?,
        None => Relief::default(),
    };
    if let Some(d) = &body.displacement_map {
        if body.shadows.is_some() {
            // Limb, shading and shadows from one DEM (docs/SCENE.md).
            return Err(Error::invalid(
                "body.displacement_map",
                "a body with `shadows` takes its displacement from the shadows' DEM: remove `displacement_map` and set `shadows.displace = true`",
            ));
        }
        if !d.scale.is_finite() {
            return Err(Error::invalid("body.displacement_map.scale", "not finite"));
        }
        let mut height = load_map(body_base, &d.path, "body.displacement_map.path")?;
        height.scale(d.scale);
        relief.set_height(height);
    }
    if let Some(files) = body.albedo_tiles.as_deref().filter(|f| !f.is_empty()) {
        let set = tiles::load_albedo_tiles(files, body_base, "body.albedo_tiles")?;
        relief.albedo_tiles = Some(std::sync::Arc::new(set));
    }
    if let Some(n) = &body.normal_map {
        let p = resolve(body_base, &n.path);
        relief.normals = Some(
            NormalMap::load(&p)
                .map_err(|e| Error::invalid("body.normal_map.path", e.to_string()))?,
        );
    }
    Ok(Body {
        radius,
        reflectance,
        albedo_map,
        albedo_spectrum,
        relief,
        parameter_maps,
        lime_reference: body.lime_reference,
    })
}

/// An albedo or parameter map's file and how its values are stretched.
struct MapSpec<'a> {
    path: &'a Path,
    min: f64,
    max: f64,
    power: f64,
    encoding: MapEncoding,
    /// Whether values must be ≥ 0 (an albedo; some parameters may be < 0).
    nonneg: bool,
}

impl MapSpec<'_> {
    /// The map read and stretched to [min, max] by `power`; errors name
    /// `key`.{min, max, power, path}.
    fn load(&self, base: &Path, key: &str) -> Result<EquirectMap> {
        let (lo, hi) = (self.min, self.max);
        let floor_ok = !self.nonneg || lo >= 0.0;
        if !(lo.is_finite() && hi.is_finite() && floor_ok && hi >= lo) {
            let need = if self.nonneg {
                "0 <= min <= max"
            } else {
                "min <= max"
            };
            return Err(Error::invalid(key, format!("need finite {need}")));
        }
        let (p_lo, p_hi) = MAP_POWER_RANGE;
        if !(self.power >= p_lo && self.power <= p_hi) {
            return Err(Error::invalid(
                format!("{key}.power"),
                format!("need {p_lo} <= power <= {p_hi}, got {}", self.power),
            ));
        }
        let path_key = format!("{key}.path");
        let mut map = match self.encoding {
            MapEncoding::Linear => load_map(base, self.path, &path_key)?,
            MapEncoding::Srgb => {
                let p = resolve(base, self.path);
                EquirectMap::load_srgb(&p).map_err(|e| Error::invalid(&path_key, e.to_string()))?
            }
        };
        map.stretch_power(lo, hi, self.power);
        Ok(map)
    }
}

/// The body's `parameter_maps`: each names a parameter of its model, once,
/// with a range the parameter accepts.
fn parameter_maps(
    body: &BodyFile,
    model: &Reflectance,
    base: &Path,
) -> Result<Vec<(MappedParameter, EquirectMap)>> {
    let files = body.parameter_maps.as_deref().unwrap_or_default();
    if files.len() > MAX_PARAMETER_MAPS {
        return Err(Error::invalid(
            "body.parameter_maps",
            format!("at most {MAX_PARAMETER_MAPS} maps, got {}", files.len()),
        ));
    }
    let mut maps: Vec<(MappedParameter, EquirectMap)> = Vec::new();
    for (i, f) in files.iter().enumerate() {
        let key = format!("body.parameter_maps[{i}]");
        let name = crate::error::abbreviate(&f.parameter, 40);
        if f.parameter == "albedo" || f.parameter == "w" {
            return Err(Error::invalid(
                format!("{key}.parameter"),
                format!("`{name}` is the albedo parameter: map it with albedo_map"),
            ));
        }
        let parameter = MappedParameter::of(model, &f.parameter).map_err(|known| {
            Error::invalid(
                format!("{key}.parameter"),
                format!(
                    "`{name}` is not a parameter of {} (accepted: {known})",
                    model.name()
                ),
            )
        })?;
        if maps.iter().any(|(p, _)| *p == parameter) {
            return Err(Error::invalid(
                format!("{key}.parameter"),
                format!("`{name}` is mapped twice"),
            ));
        }
        if !(parameter.accepts(f.min) && parameter.accepts(f.max)) {
            return Err(Error::invalid(
                &key,
                format!(
                    "{}: min {} and max {} must both be valid values",
                    parameter.name(),
                    f.min,
                    f.max
                ),
            ));
        }
        let spec = MapSpec {
            path: &f.path,
            min: f.min,
            max: f.max,
            power: f.power,
            encoding: f.encoding,
            nonneg: false,
        };
        maps.push((parameter, spec.load(base, &key)?));
    }
    Ok(maps)
}

impl Body {
    /// Read a body file (`[body]` table, as `configs/bodies/moon.toml`);
    /// errors name the file.
    pub fn from_file(path: &Path) -> Result<Self> {
        let text = crate::infile::read_text_bounded(path, crate::infile::CONFIG_LIMIT)?;
        let file: BodyFileOnly =
            toml::from_str(&text).map_err(|e| Error::parse(path, toml_message(&text, &e)))?;
        body_from(&file.body, path.parent().unwrap_or(Path::new(".")))
            .map_err(|e| Error::parse(path, e.to_string()))
    }
}

fn resolve(base: &Path, p: &Path) -> PathBuf {
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        base.join(p)
    }
}

fn load_map(base: &Path, p: &Path, field: &str) -> Result<EquirectMap> {
    let path = resolve(base, p);
    if !path.exists() {
        return Err(Error::invalid(
            field,
            format!("map file {} does not exist", path.display()),
        ));
    }
    EquirectMap::load(&path).map_err(|e| Error::invalid(field, e.to_string()))
}

fn response(r: &ResponseFile, base: &Path, field: &str) -> Result<Response> {
    match r {
        ResponseFile::Constant(v) if v.is_finite() && *v >= 0.0 => Ok(Response::Constant(*v)),
        ResponseFile::Constant(v) => Err(Error::invalid(field, format!("must be >= 0, got {v}"))),
        ResponseFile::Table(p) => Table::from_csv(&resolve(base, p))
            .map(Response::Table)
            .map_err(|e| Error::invalid(field, e.to_string())),
        ResponseFile::Normalised(t) => {
            let table = Table::from_csv(&resolve(base, &t.path))
                .map_err(|e| Error::invalid(field, e.to_string()))?;
            match t.normalisation {
                Normalisation::Photon => Ok(Response::Table(table)),
                Normalisation::Energy if field.ends_with("quantum_efficiency") => {
                    Ok(Response::AmpsPerWatt(table))
                }
                Normalisation::Energy => Err(Error::invalid(
                    field,
                    "a transmission is a fraction: normalisation = \"energy\" applies to quantum_efficiency only",
                )),
            }
        }
    }
}

/// Build a camera from its `[camera]` table.
pub fn camera_from(c: &CameraFile, base: &Path) -> Result<Camera> {
    let [width, height] = c.resolution;
    check_resolution(width, height)?;
    let pitch = within(c.pixel_pitch, 1e-8, 0.1, "camera.pixel_pitch")?;
    let focal_length = match (c.focal_length, c.fov_deg) {
        (Some(f), None) => within(f, 1e-5, 1e6, "camera.focal_length")?,
        (None, Some(fov)) => {
            if !(fov.is_finite() && fov > 0.0 && fov < 180.0) {
                return Err(Error::invalid("camera.fov_deg", "must be in (0, 180)"));
            }
            let f = width as f64 * pitch / 2.0 / (fov.to_radians() / 2.0).tan();
            within(f, 1e-5, 1e6, "camera.fov_deg (as a focal length in m)")?
        }
        (Some(_), Some(_)) => {
            return Err(Error::invalid(
                "camera.focal_length",
                "give either focal_length or fov_deg, not both",
            ))
        }
        (None, None) => {
            return Err(Error::invalid(
                "camera.focal_length",
                "missing: give focal_length or fov_deg",
            ))
        }
    };
    let [cx, cy] = c
        .principal_point
        .unwrap_or([width as f64 / 2.0, height as f64 / 2.0]);
    if !(cx.is_finite() && cy.is_finite()) {
        return Err(Error::invalid("camera.principal_point", "not finite"));
    }
    let f_number = within(c.f_number, 0.1, 1e4, "camera.f_number")?;
    let exposure = within(c.exposure, 1e-12, 1e6, "camera.exposure")?;
    let full_well = within(c.full_well, 1.0, 1e30, "camera.full_well")?;
    if c.bits == 0 || c.bits > 32 {
        return Err(Error::invalid("camera.bits", "must be 1..=32"));
    }
    if !(c.gain.is_finite() && c.gain >= 0.0) {
        return Err(Error::invalid("camera.gain", "must be >= 0"));
    }
    let band = c.band;
    if !(band[0].is_finite() && band[1].is_finite() && band[0] > 0.0 && band[1] > band[0]) {
        return Err(Error::invalid(
            "camera.band",
            "need 0 < lower < upper wavelength [m]",
        ));
    }
    if band[1] > 1e-3 {
        return Err(Error::invalid(
            "camera.band",
            "wavelengths are in metres (e.g. 450e-9), not nanometres",
        ));
    }
    let max_dn = 2f64.powi(c.bits as i32) - 1.0;
    let sensor = c.sensor.as_ref().map(|s| s.check(max_dn)).transpose()?;
    let psf = c
        .psf
        .as_ref()
        .map(|p| {
            let psf = match *p {
                PsfFile::Gaussian { sigma_px } => Psf::Gaussian { sigma_px },
                PsfFile::Airy { wavelength } => Psf::Airy {
                    f_number,
                    wavelength_m: wavelength,
                    pitch_m: pitch,
                },
            };
            psf.validate("camera.psf").map(|_| psf)
        })
        .transpose()?;
    let distortion = lens_from(c, base, focal_length / pitch)?;
    let quantum_efficiency = response(&c.quantum_efficiency, base, "camera.quantum_efficiency")?;
    let transmission = response(&c.transmission, base, "camera.transmission")?;
    check_band_response(&quantum_efficiency, &transmission, band)?;
    let gain = if c.gain > 0.0 {
        c.gain
    } else {
        max_dn / full_well
    };
    let pinhole = match &distortion {
        Some(lens) => lens.pinhole(),
        None => Pinhole {
            width,
            height,
            fx: focal_length / pitch,
            fy: focal_length / pitch,
            cx,
            cy,
        },
    };
    Ok(Camera {
        pinhole,
        pixel_pitch: pitch,
        focal_length,
        f_number,
        exposure,
        full_well,
        bits: c.bits,
        gain,
        band,
        quantum_efficiency,
        transmission,
        sensor,
        psf,
        distortion,
        sensor_frame: 0,
    })
}

/// Default sample points per pixel and axis of the distortion's resampling.
const DISTORTION_SUPERSAMPLE: usize = 4;

/// `camera.distortion`: the intrinsics file (its errors name it), which
/// must match `camera.resolution` and, within 5 %, the focal length in
/// pixels `fx_nominal` the pupil is sized from; it replaces
/// `principal_point`.
fn lens_from(
    c: &CameraFile,
    base: &Path,
    fx_nominal: f64,
) -> Result<Option<crate::optics::distortion::Lens>> {
    let Some(path) = &c.distortion else {
        return match c.distortion_supersample {
            Some(_) => Err(Error::invalid(
                "camera.distortion_supersample",
                "given without camera.distortion",
            )),
            None => Ok(None),
        };
    };
    let file = resolve(base, path);
    // The file's own errors name it and its key; this names the scene's.
    let k = crate::instruments::intrinsics::CameraIntrinsics::load(&file)
        .map_err(|e| Error::invalid("camera.distortion", e.to_string()))?;
    let named = |e: Error| Error::invalid("camera.distortion", format!("{}: {e}", file.display()));
    if [k.width, k.height] != c.resolution {
        return Err(named(Error::Other(format!(
            "{}×{} px, camera.resolution is {}×{}",
            k.width, k.height, c.resolution[0], c.resolution[1]
        ))));
    }
    if c.principal_point.is_some() {
        return Err(Error::invalid(
            "camera.principal_point",
            "camera.distortion's file gives the principal point: remove one of them",
        ));
    }
    let fx = k.camera_matrix[0][0];
    if (fx / fx_nominal - 1.0).abs() > 0.05 {
        return Err(named(Error::Other(format!(
            "fx = {fx} px differs from focal_length / pixel_pitch = {fx_nominal} px by over 5 %"
        ))));
    }
    let supersample = c.distortion_supersample.unwrap_or(DISTORTION_SUPERSAMPLE);
    let lens = crate::optics::distortion::Lens::new(k, supersample).map_err(named)?;
    // The ideal grid's images and the lens tables come on top of the
    // camera's images (checked by `check_resolution`), before either is
    // allocated.
    let (ideal, camera) = (
        (lens.ideal.width * lens.ideal.height) as f64,
        (lens.intrinsics.width * lens.intrinsics.height) as f64,
    );
    let bytes =
        ideal * IMAGE_BYTES_PER_PIXEL + camera * (IMAGE_BYTES_PER_PIXEL + LENS_BYTES_PER_PIXEL);
    if bytes > MAX_IMAGE_BYTES {
        return Err(named(Error::Other(format!(
            "the {}×{} px ideal grid and the lens tables imply {:.1} GiB with the images, more than the {:.0} GiB limit",
            lens.ideal.width,
            lens.ideal.height,
            bytes / 1024f64.powi(3),
            MAX_IMAGE_BYTES / 1024f64.powi(3)
        ))));
    }
    Ok(Some(lens))
}

/// The `state.epoch` text of a scene file, if it gives one (the labels
/// record it; the scene itself keeps only the poses it implies).
pub fn epoch_text(path: &Path) -> Result<Option<String>> {
    let text = crate::infile::read_text_bounded(path, crate::infile::CONFIG_LIMIT)?;
    let table: toml::Table =
        toml::from_str(&text).map_err(|e| Error::parse(path, toml_message(&text, &e)))?;
    Ok(table
        .get("state")
        .and_then(|s| s.get("epoch"))
        .and_then(|e| e.as_str())
        .map(str::to_string))
}

/// Most memory a render's images may imply [bytes].
pub const MAX_IMAGE_BYTES: f64 = 2.0 * 1024.0 * 1024.0 * 1024.0;

/// Bytes per pixel a render holds: the renderer's flux and solid angles,
/// radiance, effective radiance, electron rate and electrons (f32 each),
/// DN and its PNG copy (u16 each), the preview (u8), the interior mask, the
/// sensor's PRNU and DSNU maps (f32) and its charge (f64): 46, rounded up.
/// The workers' accumulation buffers (one per thread, over the body's
/// region only) come on top; they are left out so the bound does not
/// depend on the machine.
pub const IMAGE_BYTES_PER_PIXEL: f64 = 48.0;

/// Bytes per camera pixel of a lens's tables (`optics::distortion::Resampler`):
/// corner positions (24), centre direction (24), solid angle (4) and the
/// resampling's weight table once every band is built (68: 8.0 terms of
/// 8 bytes per pixel and a 4-byte row start, measured for
/// configs/bench_lens_intrinsics.toml at 4 × 4 samples).
pub const LENS_BYTES_PER_PIXEL: f64 = 120.0;

/// `camera.resolution` bounded by the memory its images imply, before
/// anything is allocated.
fn check_resolution(width: usize, height: usize) -> Result<()> {
    if width == 0 || height == 0 || width > 65_536 || height > 65_536 {
        return Err(Error::invalid(
            "camera.resolution",
            "must be between 1 and 65536 px",
        ));
    }
    let per_pixel = IMAGE_BYTES_PER_PIXEL;
    let bytes = (width * height) as f64 * per_pixel;
    if bytes > MAX_IMAGE_BYTES {
        return Err(Error::invalid(
            "camera.resolution",
            format!(
                "{width} x {height} px implies {:.1} GiB of images ({per_pixel} bytes per pixel), more than the {:.0} GiB limit (at most {:.0} Mpx)",
                bytes / 1024f64.powi(3),
                MAX_IMAGE_BYTES / 1024f64.powi(3),
                MAX_IMAGE_BYTES / per_pixel / 1e6
            ),
        ));
    }
    Ok(())
}

/// A camera must see something: ∫ QE T λ/(hc) dλ over the band > 0 (a QE
/// or transmission of 0 would make every camera-weighted figure 0/0).
fn check_band_response(qe: &Response, transmission: &Response, band: [f64; 2]) -> Result<()> {
    let integral = crate::radiometry::spectrum::response_integral(qe, transmission, band);
    if integral.is_finite() && integral > 0.0 {
        return Ok(());
    }
    let qe_alone =
        crate::radiometry::spectrum::response_integral(qe, &Response::Constant(1.0), band);
    let key = if qe_alone > 0.0 {
        "camera.transmission"
    } else {
        "camera.quantum_efficiency"
    };
    Err(Error::invalid(
        key,
        format!(
            "the camera's band response (QE x transmission) integrates to {integral:e} over camera.band [{:e}, {:e}] m: the camera would detect nothing",
            band[0], band[1]
        ),
    ))
}
