//! The simulated facility camera reads out through the one detector model
//! (`src/sensor`, as `render`): the photon-transfer analysis of
//! tests/common/ptc.rs (EMVA 1288 §6, as tests/sensor_emva.rs: temporal
//! variance from the difference of two captures, gain from the
//! mean–variance slope, dark current from the dark signal's growth with
//! exposure, read noise from the dark variance less the quantisation noise
//! 1/12 DN²) of its captures recovers its configured gain, read noise and dark current within 2 %;
//! dark frames have the closed-form mean and variance and row means the
//! row offset's variance; the non-linearity follows e (1 − β e / FW).

use optistim::simfacility::SimFacility;

mod common;
use common::ptc::{mean, pair_stats, variance, PhotonTransfer};
use common::simfacility::{show_uniform, SimToml};

/// Camera size: wide rows for the row means, many pixels for the PTC.
const W: usize = 128;
const H: usize = 256;

/// The small facility's screen (one frame kept: the frame shown is taken
/// to have been up for any exposure) at full white, seen by a 128×256
/// camera at 40 000 px with `camera` keys added.
fn facility(camera: &str) -> SimFacility {
    let f = SimToml::small()
        .seed(11)
        .with("screen", "history_frames = 1")
        .with(
            "camera",
            &format!("resolution = [{W}, {H}]\nfx = 40000.0\nfy = 40000.0\ncx = 64.0\ncy = 128.0"),
        )
        .with("camera", "supersample = 1")
        .with("camera", camera)
        .facility();
    show_uniform(&f, 255);
    f
}

fn light(f: &SimFacility, t: f64) -> Vec<f64> {
    as_f64(&f.capture_last(t).unwrap().data)
}

fn dark(f: &SimFacility, t: f64) -> Vec<f64> {
    as_f64(&f.capture_dark(t).unwrap().data)
}

fn as_f64(v: &[f32]) -> Vec<f64> {
    v.iter().map(|&x| x as f64).collect()
}

#[test]
fn photon_transfer_recovers_gain_read_noise_and_dark_current() {
    const GAIN: f64 = 0.25;
    const READ_NOISE: f64 = 8.0;
    const DARK_CURRENT: f64 = 200.0;
    const FULL_WELL: f64 = 20_000.0;
    let f = facility(&format!(
        "gain = {GAIN}\nfull_well = {FULL_WELL:e}\nbias_dn = 100.0\nread_noise = {READ_NOISE}\n\
         dark_current = {DARK_CURRENT}\nprnu = 0.01\nvignetting = 0.02"
    ));
    // The brightest pixel's signal rate, to place the exposures (not truth:
    // one capture, dark and bias removed).
    let probe = light(&f, 0.01);
    let max_rate = (probe.iter().copied().fold(0.0, f64::max) - 100.0) / GAIN / 0.01;

    // Each pair two successive captures.
    let ptc = PhotonTransfer::measure(FULL_WELL, max_rate, |which, t| {
        let capture = || {
            if which.is_light() {
                light(&f, t)
            } else {
                dark(&f, t)
            }
        };
        let a = capture();
        pair_stats(&a, &capture())
    });
    ptc.assert_recovers(GAIN, READ_NOISE, DARK_CURRENT, 0.02);
}

#[test]
fn dark_frames_have_the_closed_form_mean_variance_and_row_offsets() {
    // Gain 1 DN/e⁻, bias 100 DN, 1000 e⁻/s over 10 ms (10 e⁻), read noise
    // 3 e⁻, row noise 5 e⁻.
    let (bias, dark_e, read, row) = (100.0, 10.0, 3.0, 5.0);
    let f = facility(&format!(
        "gain = 1.0\nfull_well = 1.0e5\nbias_dn = {bias}\ndark_current = 1000.0\n\
         read_noise = {read}\nrow_noise = {row}"
    ));
    let frames = 100;
    let captures: Vec<Vec<f64>> = (0..frames).map(|_| dark(&f, 0.01)).collect();
    let all: Vec<f64> = captures.iter().flatten().copied().collect();
    // Per pixel: Poisson dark + read + row + quantisation.
    let pixel_var = dark_e + read * read + row * row + 1.0 / 12.0;
    let n = all.len() as f64;
    let got_mean = mean(&all);
    // The frame's rows share offsets: the mean's standard error is that of
    // frames × H row offsets plus the pixel noise.
    let se = ((row * row) / (frames * H) as f64 + pixel_var / n).sqrt();
    assert!(
        (got_mean - bias - dark_e).abs() < 4.0 * se,
        "dark mean {got_mean} DN, formula {}",
        bias + dark_e
    );
    // Temporal variance per pixel, from differences of consecutive frames.
    let diffs: Vec<f64> = captures
        .chunks(2)
        .flat_map(|p| {
            p[0].iter()
                .zip(&p[1])
                .map(|(a, b)| a - b)
                .collect::<Vec<_>>()
        })
        .collect();
    let got_var = variance(&diffs) / 2.0;
    // The row offsets make the differences correlated along rows: the
    // estimate's spread is that of frames / 2 × H independent rows.
    let rel = (2.0 / (frames / 2 * H) as f64).sqrt();
    assert!(
        (got_var / pixel_var - 1.0).abs() < 4.0 * rel,
        "dark variance {got_var} DN², formula {pixel_var}"
    );
    // Row means: var = row² + (dark + read² + 1/12) / W.
    let row_means: Vec<f64> = captures
        .iter()
        .flat_map(|c| c.chunks(W).map(mean).collect::<Vec<_>>())
        .collect();
    let expected = row * row + (dark_e + read * read + 1.0 / 12.0) / W as f64;
    let got = variance(&row_means);
    let rel = (2.0 / row_means.len() as f64).sqrt();
    eprintln!("row-mean variance {got:.4}, formula {expected:.4} (±{rel:.4} relative)");
    assert!(
        (got / expected - 1.0).abs() < 4.0 * rel,
        "row-mean variance {got}, formula {expected}"
    );
}

/// e (1 − β e / FW) up to the full well, its value there beyond.
fn non_linear(e: f64, beta: f64, fw: f64) -> f64 {
    let e = e.min(fw);
    e * (1.0 - beta * e / fw)
}

#[test]
fn non_linearity_follows_its_curve_to_the_full_well() {
    let (beta, fw, bias) = (0.05, 50_000.0, 100.0);
    let keys = |b: f64| {
        format!("gain = 1.0\nfull_well = {fw:e}\nbias_dn = {bias}\nshot_noise = false\nnonlinearity = {b}")
    };
    // Linear electrons per pixel from a linear twin at 90 % of the full
    // well (±0.5 e⁻ of rounding), scaled with the exposure.
    let linear = facility(&keys(0.0));
    let probe = light(&linear, 0.01);
    let max_rate = (probe.iter().copied().fold(0.0, f64::max) - bias) / 0.01;
    let t_ref = 0.9 * fw / max_rate;
    let e_ref: Vec<f64> = light(&linear, t_ref).iter().map(|d| d - bias).collect();
    let f = facility(&keys(beta));
    let mut worst = 0.0f64;
    for fill in [0.1, 0.3, 0.5, 0.7, 0.9, 1.0, 1.2, 1.5] {
        let t = fill * fw / max_rate;
        let dn = light(&f, t);
        let scale = t / t_ref;
        for (d, e) in dn.iter().zip(&e_ref) {
            let expected = bias + non_linear(e * scale, beta, fw);
            // Rounding: the twin's ±0.5 e⁻ scaled, and this frame's ±0.5.
            let err = (d - expected).abs() - 0.5 * scale;
            worst = worst.max(err);
            assert!(err <= 0.5 + 1e-6, "fill {fill}: {d} DN, curve {expected}");
        }
        // The deficit at the brightest pixel is β e / FW of the signal: not
        // the linear response.
        if fill >= 0.5 {
            let top = dn.iter().copied().fold(0.0, f64::max) - bias;
            assert!(
                top < (1.0 - 0.4 * beta) * fill.min(1.0) * fw,
                "fill {fill}: {top}"
            );
        }
    }
    eprintln!("worst excess over the rounding bound: {worst:.3} DN");
}
