//! The offline planner of `optistim render` and `bench`: given a per-pixel
//! error target, the cheapest settings of the ladder
//! ([`crate::fidelity::planner_ladder`]) whose measured error on the scene
//! meets it. Like the governor's pre-flight, the error is measured, not
//! read from a table: one converged render of the scene
//! ([`crate::fidelity::reference_settings`]), then the ladder's settings
//! from the coarsest up until one meets the target.
//!
//! The error planned on is the interior p99: the 99th percentile of
//! |render / converged − 1| over the pixels integrated per pixel (the
//! disk's interior) above [`PIXEL_FLOOR`] of the peak. Edge pixels (limb,
//! terminator) come from the lune's caps at the scene's density, which no
//! step changes; their p99 is reported beside it.
//!
//! Where the caps draw most of the disk in the ladder's renders (a
//! displaced relief, `geometry = "distant"`: fewer than
//! [`MIN_INTERIOR_SHARE`] of its pixels are interior), the interior says nothing about the image:
//! the whole disk's p99 is planned on instead, the ladder gains a step at
//! [`CAPS_STEP_DENSITY`] caps per pixel, and the converged render takes
//! [`CAPS_REFERENCE_DENSITY`].

use std::time::Instant;

use crate::error::{Error, Result};
use crate::fidelity::{self, Step};
pub use crate::fidelity::{Plan, StepMeasure};
use crate::render::Renderer;
use crate::render_settings::{check_pixel_error_target, RenderSettings};
use crate::scene::Scene;

/// Pixels below this fraction of the reference's peak are left out of
/// the per-pixel errors (as in `optistim bench`).
pub const PIXEL_FLOOR: f32 = 0.01;

/// Map parts per cap and axis of the planner's converged render (the
/// governor's takes 2): on the benchmark Moon the converged render with
/// 2×2 parts is itself 1.1e-3 off (interior p99) a render at 6 caps per
/// pixel with 4×4 parts, with 4×4 parts 3.8e-4 (`tests/render_planner.rs`
/// measures the planner against that render).
pub const REFERENCE_PARTS: usize = 4;

/// Share of the disk's pixels that must be interior for the interior p99
/// to be the planned error.
pub const MIN_INTERIOR_SHARE: f64 = 0.5;

/// Caps per pixel and axis of the step added above the scene's own where
/// the caps draw the disk: half the converged render's.
pub const CAPS_STEP_DENSITY: f64 = 2.0;

/// Caps per pixel and axis of the converged render where the caps draw
/// the disk. On `configs/moon.toml` (relief at 30°, every pixel
/// from caps) 1, 2 and 4 caps per pixel are 20 %, 8.3 % and 2.6 % (p99)
/// off a render at 6 (BENCHMARKS.md, "Relief: per-pixel error").
pub const CAPS_REFERENCE_DENSITY: f64 = 4.0;

/// Which pixels the planned error is taken over.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Judged {
    /// The pixels integrated per pixel.
    Interior,
    /// Every disk pixel above the floor (the caps draw most of them).
    Disk,
}

impl Judged {
    pub fn name(self) -> &'static str {
        match self {
            Judged::Interior => "interior",
            Judged::Disk => "disk",
        }
    }

    /// The planned error of a measured step.
    pub fn error(self, m: &StepMeasure) -> f64 {
        match self {
            Judged::Interior => m.interior_pixel_error_p99,
            Judged::Disk => m.pixel_error_p99,
        }
    }
}

/// A ladder on one scene with its converged render, each step measured
/// once when first asked for.
pub struct Planner<'a> {
    scene: &'a Scene,
    renderer: Renderer,
    ladder: Vec<Step>,
    reference: Vec<f32>,
    judged: Judged,
    measured: Vec<Option<StepMeasure>>,
    spent: f64,
}

impl<'a> Planner<'a> {
    /// Renders `scene`'s converged reference (the ladder on the scene's
    /// own `[render]` settings). The ladder's coarsest step, which
    /// [`Planner::plan`] measures first anyway, is rendered first: it tells
    /// whether the interior or the caps draw the disk in the ladder's
    /// renders, and is kept as that step's measurement.
    pub fn new(scene: &'a Scene) -> Planner<'a> {
        let t = Instant::now();
        let mut renderer = Renderer::new(scene.camera.pinhole.clone());
        let mut ladder = fidelity::planner_ladder(&scene.render);
        let coarsest = StepRender::of(&mut renderer, scene, &ladder[ladder.len() - 1].settings);
        let judged = if coarsest.interior_share() >= MIN_INTERIOR_SHARE {
            Judged::Interior
        } else {
            Judged::Disk
        };
        let mut reference_settings = fidelity::reference_settings(&scene.render);
        reference_settings.texture_samples = REFERENCE_PARTS;
        if judged == Judged::Disk {
            reference_settings.caps_per_pixel = Some(caps_reference_density(&scene.render));
            if scene.render.density() < CAPS_STEP_DENSITY {
                ladder.insert(0, caps_step(&scene.render));
            }
        }
        renderer.render_flux(&scene.body, &scene.state, &reference_settings, None);
        let reference = renderer.flux().to_vec();
        let mut measured = vec![None; ladder.len()];
        let last = ladder.len() - 1;
        measured[last] = Some(coarsest.measure(last, &ladder[last].label, &reference));
        Planner {
            scene,
            renderer,
            ladder,
            reference,
            judged,
            measured,
            spent: t.elapsed().as_secs_f64(),
        }
    }

    /// Which pixels the planned error is taken over.
    pub fn judged(&self) -> Judged {
        self.judged
    }

    /// The ladder, finest first.
    pub fn ladder(&self) -> &[Step] {
        &self.ladder
    }

    /// Step `i` rendered and compared with the converged render.
    pub fn measure(&mut self, i: usize) -> StepMeasure {
        if let Some(m) = &self.measured[i] {
            return m.clone();
        }
        let t = Instant::now();
        let step = &self.ladder[i];
        let render = StepRender::of(&mut self.renderer, self.scene, &step.settings);
        let m = render.measure(i, &step.label, &self.reference);
        self.spent += t.elapsed().as_secs_f64();
        self.measured[i] = Some(m.clone());
        m
    }

    /// The coarsest step whose measured interior p99 meets `target`
    /// (`source`: the key or flag it came from, named in errors). A
    /// target out of (0, 1] or below what the finest step reaches is an
    /// error naming `source`.
    pub fn plan(&mut self, target: f64, source: &str) -> Result<Plan> {
        check_pixel_error_target(source, target)?;
        let mut tried = Vec::new();
        let mut chosen = None;
        for i in (0..self.ladder.len()).rev() {
            let m = self.measure(i);
            let meets = self.judged.error(&m) <= target;
            tried.push(m);
            if meets {
                chosen = Some(i);
                break;
            }
        }
        let finest = tried.last().expect("a ladder has steps").clone();
        let Some(i) = chosen else {
            return Err(Error::invalid(
                source,
                format!(
                    "{target:e} is below what the finest setting reaches on this scene ({}: {} p99 {:.2e})",
                    finest.label,
                    self.judged.name(),
                    self.judged.error(&finest)
                ),
            ));
        };
        Ok(self.report(i, target, source, tried))
    }

    fn report(&self, i: usize, target: f64, source: &str, tried: Vec<StepMeasure>) -> Plan {
        let m = tried.last().expect("the chosen step was measured").clone();
        let coarser = tried.len().checked_sub(2).map(|k| &tried[k]);
        let (judged, error) = (self.judged.name(), |m: &StepMeasure| self.judged.error(m));
        let mut why = match coarser {
            Some(c) => format!(
                "{} is the cheapest of the {} settings whose {judged} p99 against a converged render ({:.2e}) meets {target:e}; the next cheaper, {}, measured {:.2e}",
                m.label,
                self.ladder.len(),
                error(&m),
                c.label,
                error(c)
            ),
            None => format!(
                "{} is the cheapest of the {} settings and its {judged} p99 against a converged render ({:.2e}) meets {target:e}",
                m.label,
                self.ladder.len(),
                error(&m)
            ),
        };
        if self.judged == Judged::Disk {
            why.push_str(&format!(
                "; judged over the whole disk: fewer than {:.0} % of its pixels are interior (the caps draw it)",
                MIN_INTERIOR_SHARE * 100.0
            ));
        }
        Plan {
            max_pixel_error: target,
            source: source.to_string(),
            step: i,
            label: m.label.clone(),
            settings: self.ladder[i].settings.clone(),
            judged: judged.to_string(),
            predicted_pixel_error: error(&m),
            predicted_pixel_error_all: m.pixel_error_p99,
            predicted_flux_error: m.flux_error,
            why,
            ladder: self.ladder.iter().map(|s| s.label.clone()).collect(),
            measured: tried,
            reference_caps_per_pixel: match self.judged {
                Judged::Interior => fidelity::REFERENCE_DENSITY,
                Judged::Disk => caps_reference_density(&self.scene.render),
            },
            reference_map_parts: REFERENCE_PARTS,
            planning_ms: self.spent * 1e3,
        }
    }
}

/// One step's render: its flux, which pixels were integrated per pixel,
/// and how long it took.
struct StepRender {
    flux: Vec<f32>,
    interior: Vec<bool>,
    render_ms: f64,
}

impl StepRender {
    fn of(renderer: &mut Renderer, scene: &Scene, settings: &RenderSettings) -> StepRender {
        let t = Instant::now();
        renderer.render_flux(&scene.body, &scene.state, settings, None);
        let render_ms = t.elapsed().as_secs_f64() * 1e3;
        let width = renderer.camera().width;
        let flux = renderer.flux().to_vec();
        let interior = (0..flux.len())
            .map(|k| renderer.is_interior_pixel(k % width, k / width))
            .collect();
        StepRender {
            flux,
            interior,
            render_ms,
        }
    }

    /// The render compared with the converged `reference`.
    fn measure(&self, step: usize, label: &str, reference: &[f32]) -> StepMeasure {
        let interior = |k: usize| self.interior[k];
        StepMeasure {
            step,
            label: label.to_string(),
            interior_pixel_error_p99: fidelity::pixel_error_p99(
                &self.flux,
                reference,
                PIXEL_FLOOR,
                interior,
            ),
            pixel_error_p99: fidelity::pixel_error_p99(&self.flux, reference, PIXEL_FLOOR, |_| {
                true
            }),
            flux_error: fidelity::flux_error(&self.flux, reference),
            render_ms: self.render_ms,
        }
    }

    /// Share of the lit pixels (flux above [`PIXEL_FLOOR`] of the peak)
    /// that were integrated per pixel; 1 with none lit.
    fn interior_share(&self) -> f64 {
        let peak = self.flux.iter().copied().fold(0.0f32, f32::max);
        let (mut n, mut interior) = (0usize, 0usize);
        for (&v, &inside) in self.flux.iter().zip(&self.interior) {
            if v > PIXEL_FLOOR * peak {
                n += 1;
                interior += usize::from(inside);
            }
        }
        if n == 0 {
            return 1.0;
        }
        interior as f64 / n as f64
    }
}

/// The scene's settings at [`CAPS_STEP_DENSITY`] caps per pixel.
fn caps_step(base: &RenderSettings) -> Step {
    let mut settings = base.clone();
    settings.caps_per_pixel = Some(CAPS_STEP_DENSITY);
    Step {
        label: format!("{CAPS_STEP_DENSITY} caps per pixel"),
        settings,
    }
}

/// The converged render's caps per pixel where the caps draw the disk:
/// [`CAPS_REFERENCE_DENSITY`], or twice the scene's own if that is more.
fn caps_reference_density(base: &RenderSettings) -> f64 {
    CAPS_REFERENCE_DENSITY.max(2.0 * base.density())
}

/// The target of a render: `flag` (`--max-pixel-error`) if given, else
/// the scene's `[render] max_pixel_error`, with the name to report it by.
pub fn target(flag: Option<f64>, scene: &Scene) -> Option<(f64, &'static str)> {
    flag.map(|t| (t, "--max-pixel-error")).or_else(|| {
        scene
            .render
            .max_pixel_error
            .map(|t| (t, "render.max_pixel_error"))
    })
}
