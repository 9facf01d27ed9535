//! The photon-transfer analysis (EMVA 1288 §6) the detector tests run on
//! any camera that reads out pairs of frames: temporal variance from the
//! difference of two frames, gain from the mean–variance slope, dark
//! current from the dark signal's growth with exposure, read noise from the
//! dark variance less the quantisation noise 1/12 DN². Written here, not
//! taken from `src/sensor`.

/// Exposures of the dark ramp [s]: the dark signal's slope is K × dark current.
const DARK_TIMES: [f64; 4] = [0.5, 1.0, 2.0, 4.0];
/// Light levels of the transfer curve, as fractions of the full well.
const FILLS: [f64; 8] = [0.02, 0.05, 0.1, 0.2, 0.35, 0.5, 0.65, 0.8];
/// The short exposure of the read-noise pair [s].
const T_READ: f64 = 1e-6;

/// The pair of frames the analysis asks for, numbered within its kind (a
/// camera whose frames are seeded by number gives each pair its own).
#[derive(Clone, Copy, Debug)]
pub enum Pair {
    /// The k-th dark pair of the dark ramp.
    DarkRamp(usize),
    /// The k-th lit pair of the transfer curve.
    Light(usize),
    /// The dark pair at the k-th lit pair's exposure.
    DarkAtLight(usize),
    /// The dark pair at the short exposure.
    ReadNoise,
}

impl Pair {
    pub fn is_light(self) -> bool {
        matches!(self, Pair::Light(_))
    }
}

/// What the analysis recovered.
#[derive(Clone, Copy, Debug)]
pub struct PhotonTransfer {
    /// DN per electron.
    pub gain: f64,
    /// Electrons rms.
    pub read_noise: f64,
    /// Electrons per second.
    pub dark_current: f64,
}

impl PhotonTransfer {
    /// Runs the analysis: `pair(which, t)` gives the mean and temporal
    /// variance (`pair_stats`) of two frames of exposure `t`; the lit
    /// exposures fill the brightest pixel, which collects `max_rate` e⁻/s,
    /// from 2 % to 80 % of `full_well`.
    pub fn measure(
        full_well: f64,
        max_rate: f64,
        mut pair: impl FnMut(Pair, f64) -> (f64, f64),
    ) -> PhotonTransfer {
        let dark_means: Vec<f64> = DARK_TIMES
            .iter()
            .enumerate()
            .map(|(k, &t)| pair(Pair::DarkRamp(k), t).0)
            .collect();
        let (_, dark_slope) = fit_line(&DARK_TIMES, &dark_means);
        let (mut signal, mut variance) = (Vec::new(), Vec::new());
        for (k, fill) in FILLS.iter().enumerate() {
            let t = fill * full_well / max_rate;
            let (mu, var) = pair(Pair::Light(k), t);
            let (mu_dark, var_dark) = pair(Pair::DarkAtLight(k), t);
            signal.push(mu - mu_dark);
            variance.push(var - var_dark);
        }
        let (_, gain) = fit_line(&signal, &variance);
        let dark_current = dark_slope / gain;
        // σ²_dark = K² (σ_r² + D t) + 1/12 at a short exposure.
        let (_, var0) = pair(Pair::ReadNoise, T_READ);
        let read_noise = ((var0 - 1.0 / 12.0) / (gain * gain) - dark_current * T_READ).sqrt();
        PhotonTransfer {
            gain,
            read_noise,
            dark_current,
        }
    }

    /// Asserts each recovered value within `tolerance` (relative) of the
    /// configured one.
    pub fn assert_recovers(&self, gain: f64, read_noise: f64, dark_current: f64, tolerance: f64) {
        for (name, got, truth) in [
            ("gain", self.gain, gain),
            ("read noise", self.read_noise, read_noise),
            ("dark current", self.dark_current, dark_current),
        ] {
            eprintln!("{name}: recovered {got:.5}, configured {truth}");
            assert!(
                (got / truth - 1.0).abs() < tolerance,
                "{name}: recovered {got}, configured {truth}"
            );
        }
    }
}

pub fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

/// Sample variance (n − 1).
pub fn variance(v: &[f64]) -> f64 {
    let m = mean(v);
    v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64
}

/// EMVA 1288: mean of two frames and the temporal variance var(A − B) / 2
/// (the fixed pattern cancels in the difference).
pub fn pair_stats(a: &[f64], b: &[f64]) -> (f64, f64) {
    let diff: Vec<f64> = a.iter().zip(b).map(|(x, y)| x - y).collect();
    ((mean(a) + mean(b)) / 2.0, variance(&diff) / 2.0)
}

/// Least-squares line y = a + b x.
pub fn fit_line(x: &[f64], y: &[f64]) -> (f64, f64) {
    let (mx, my) = (mean(x), mean(y));
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx).powi(2)).sum();
    let slope = sxy / sxx;
    (my - slope * mx, slope)
}
