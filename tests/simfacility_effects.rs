//! The simulated facility's effects outside the calibration's model
//! families, each against a formula written here: the panel's channels
//! (grey spectrum = Σ tone curve × primary), the mura's amplitude and
//! period band, the level-dependent non-uniformity, the collimator's
//! decentring and thin prism, veiling glare, the camera's non-linearity and
//! row noise in dark frames.

use optistim::facility::display::Display;
use optistim::facility::lut::encode_grey;
use optistim::instruments::{Camera, CaptureRequest, Shutter};
use optistim::simfacility::SimFacility;

mod common;
use common::simfacility::{gaussian_dot_frame, show_uniform as uniform, SimToml};

const H: f64 = 6.626_070_15e-34;
const C: f64 = 299_792_458.0;
const KB: f64 = 1.380_649e-23;

/// The small facility with extra keys per section.
fn keys(screen: &str, collimator: &str, camera: &str) -> SimToml {
    SimToml::small()
        .with("screen", screen)
        .with("collimator", collimator)
        .with("camera", camera)
}

/// The same with every noise off unless `camera` turns it on.
fn quiet(screen: &str, collimator: &str, camera: &str) -> SimFacility {
    keys(screen, collimator, &format!("shot_noise = false\n{camera}")).facility()
}

fn show(f: &SimFacility, frame: &[u32]) {
    f.display().present(frame).unwrap();
}

fn capture(f: &SimFacility, exposure: f64, shutter: Shutter) -> Vec<f64> {
    f.camera()
        .capture(&CaptureRequest {
            pattern: "p".into(),
            exposure_s: exposure,
            shutter,
        })
        .unwrap()
        .data
        .iter()
        .map(|&v| v as f64)
        .collect()
}

/// Simpson's rule of `f` over [lo, hi] with n (even) intervals.
fn simpson(lo: f64, hi: f64, n: usize, f: impl Fn(f64) -> f64) -> f64 {
    let h = (hi - lo) / n as f64;
    let inner: f64 = (1..n)
        .map(|k| f(lo + k as f64 * h) * if k % 2 == 1 { 4.0 } else { 2.0 })
        .sum();
    (f(lo) + f(hi) + inner) * h / 3.0
}

// ---------------------------------------------------------------- panel

const PANEL: &str = "channel_gamma_delta = [0.1, 0.0, -0.1]\ntoe = [0.01, 0.02, 0.015]\n\
toe_width = 0.05\nshoulder = [0.03, 0.02, 0.04]\ncrosstalk = 0.01\n\
primary_edges_nm = [490.0, 580.0]\nprimary_edge_width_nm = 12.0";

/// The model written out: channel c's tone curve at drive x.
fn tone(c: usize, x: f64) -> f64 {
    let gamma = [2.3, 2.2, 2.1][c];
    let toe = [0.01, 0.02, 0.015][c];
    let shoulder = [0.03, 0.02, 0.04][c];
    let g = |x: f64| (x.powf(gamma) + toe * x * (-x / 0.05).exp()) * (1.0 - shoulder * x.powi(6));
    g(x) / g(1.0)
}

/// Windows red, green, blue at λ [m].
fn windows(l: f64) -> [f64; 3] {
    let s = |e: f64| 1.0 / (1.0 + (-(l - e * 1e-9) / 12e-9).exp());
    let (blue, red) = (1.0 - s(490.0), s(580.0));
    [red, 1.0 - blue - red, blue]
}

/// S(λ; level) of the flat 380–780 nm white, per metre of wavelength.
fn grey_spectrum(level: u32, l: f64) -> f64 {
    if !(380e-9..=780e-9).contains(&l) {
        return 0.0;
    }
    let x = level as f64 / 255.0;
    let t: Vec<f64> = (0..3).map(|c| tone(c, x)).collect();
    let sum: f64 = t.iter().sum();
    let e: Vec<f64> = t.iter().map(|tc| 0.97 * tc + 0.01 * sum).collect();
    let w = windows(l);
    let channels: f64 = (0..3).map(|c| e[c] * w[c]).sum();
    2.0 / 400e-9 * (0.99 * channels + 0.01)
}

#[test]
fn grey_spectrum_is_the_channels_curves_times_their_primaries() {
    let f = quiet(PANEL, "", "");
    let sun_ratio = {
        let planck = |l: f64| 1.0 / (l.powi(5) * ((H * C / (l * KB * 5772.0)).exp() - 1.0));
        simpson(450e-9, 820e-9, 20_000, planck)
            / simpson(450e-9, 820e-9, 20_000, |l| planck(l) * l / (H * C))
    };
    for level in [0u32, 10, 64, 128, 200, 255] {
        // Camera-effective radiance at the screen centre (U = 1).
        let rate = simpson(450e-9, 780e-9, 4000, |l| {
            grey_spectrum(level, l) * l / (H * C)
        });
        let expected = rate * sun_ratio;
        let got = f.true_camera_effective_radiance(level as usize, (32.0, 24.0));
        assert!(
            (got / expected - 1.0).abs() < 1e-6,
            "level {level}: {got} vs {expected}"
        );
        // The flat 380–780 nm radiometer reads ∫ S dλ.
        let total = simpson(380e-9, 780e-9, 4000, |l| grey_spectrum(level, l));
        let meter = f.true_meter_reading(level as usize);
        assert!(
            (meter / total - 1.0).abs() < 1e-6,
            "{level}: {meter} vs {total}"
        );
    }
    // The shape changes with the level: blue over red at level 64 against
    // full white, from the formula, and more than 10 % apart.
    let ratio = |level: u32| grey_spectrum(level, 450e-9) / grey_spectrum(level, 650e-9);
    let s = f.screen();
    let got =
        |level: usize| s.spectral_radiance(level, 450e-9) / s.spectral_radiance(level, 650e-9);
    assert!((got(64) / ratio(64) - 1.0).abs() < 1e-9);
    assert!((got(255) / ratio(255) - 1.0).abs() < 1e-9);
    assert!(ratio(64) / ratio(255) > 1.1, "{}", ratio(64) / ratio(255));
    // Not a power law: the curve's local exponent d ln L / d ln x differs
    // near black and near white by more than 0.3.
    let l = |x: f64| f.screen().total_radiance((x * 255.0) as usize) - 0.02;
    let slope = |a: f64, b: f64| (l(b) / l(a)).ln() / (b / a).ln();
    let (dark, bright) = (slope(8.0 / 255.0, 16.0 / 255.0), slope(200.0 / 255.0, 1.0));
    assert!((dark - bright).abs() > 0.3, "{dark} vs {bright}");
}

#[test]
fn a_decreasing_tone_curve_is_refused() {
    let err = keys("gamma = 0.6\nshoulder = [0.2, 0.0, 0.0]", "", "")
        .try_facility()
        .err()
        .expect("refused")
        .to_string();
    assert!(
        err.contains("screen.shoulder") && !err.contains('\n'),
        "{err}"
    );
}

// ----------------------------------------------------------------- mura

#[test]
fn mura_has_the_configured_rms_and_period_band() {
    let f = quiet(
        "mura_rms = 0.003\nmura_periods_px = [20.0, 200.0]\nmura_waves = 24",
        "",
        "",
    );
    let p = &f.screen().pattern;
    // 256² samples every 4 px over 1024 px; Hann window; 2-D DFT.
    let n = 256;
    let samples: Vec<f64> = (0..n * n)
        .map(|k| p.mura(4.0 * (k % n) as f64, 4.0 * (k / n) as f64))
        .collect();
    let rms = (samples.iter().map(|m| m * m).sum::<f64>() / (n * n) as f64).sqrt();
    assert!((rms / 0.003 - 1.0).abs() < 0.25, "rms {rms}");
    let hann: Vec<f64> = (0..n)
        .map(|i| 0.5 - 0.5 * (std::f64::consts::TAU * i as f64 / n as f64).cos())
        .collect();
    let windowed: Vec<f64> = (0..n * n)
        .map(|k| samples[k] * hann[k % n] * hann[k / n])
        .collect();
    let power = dft2_power(&windowed, n);
    // Radial frequency in bins of 1/1024 cycles per px: periods 20–200 px
    // are bins 5.1–51.2.
    let (mut inside, mut total) = (0.0, 0.0);
    for ky in 0..n {
        for kx in 0..n {
            let fx = if kx <= n / 2 { kx } else { n - kx } as f64;
            let fy = if ky <= n / 2 { ky } else { n - ky } as f64;
            let r = fx.hypot(fy);
            let pw = power[ky * n + kx];
            total += pw;
            if (3.0..=54.0).contains(&r) {
                inside += pw;
            }
        }
    }
    assert!(
        inside / total > 0.97,
        "{:.4} of the power in the band",
        inside / total
    );
    // The screen's map: smooth × (1 + mura) at pixel centres.
    for (u, v) in [(3usize, 5usize), (40, 20), (63, 47)] {
        let (x, y) = (u as f64 + 0.5, v as f64 + 0.5);
        let m = p.main_map[v * 64 + u] as f64;
        assert!((m - (1.0 + p.mura(x, y))).abs() < 1e-6, "{m}");
    }
}

/// |2-D DFT|² of an n × n real array (separable, brute force).
fn dft2_power(a: &[f64], n: usize) -> Vec<f64> {
    let tw: Vec<(f64, f64)> = (0..n)
        .map(|k| (std::f64::consts::TAU * k as f64 / n as f64).sin_cos())
        .collect();
    let mut rows = vec![(0.0, 0.0); n * n];
    for y in 0..n {
        for k in 0..n {
            let (mut re, mut im) = (0.0, 0.0);
            for x in 0..n {
                let (s, c) = tw[(k * x) % n];
                re += a[y * n + x] * c;
                im -= a[y * n + x] * s;
            }
            rows[y * n + k] = (re, im);
        }
    }
    let mut power = vec![0.0; n * n];
    for kx in 0..n {
        for ky in 0..n {
            let (mut re, mut im) = (0.0, 0.0);
            for y in 0..n {
                let (s, c) = tw[(ky * y) % n];
                let (r, i) = rows[y * n + kx];
                re += r * c + i * s;
                im += i * c - r * s;
            }
            power[ky * n + kx] = re * re + im * im;
        }
    }
    power
}

#[test]
fn mura_reaches_the_camera() {
    // Same facility with and without mura: the camera's ratio at a pixel is
    // 1 + m at the screen point its centre sees (the one-screen-pixel blur
    // changes m by well under its tolerance at periods ≥ 20 px).
    let with = quiet("mura_rms = 0.003\nmura_periods_px = [20.0, 60.0]", "", "");
    let without = quiet("", "", "");
    for f in [&with, &without] {
        uniform(f, 255);
    }
    let (a, b) = (
        capture(&with, 0.01, Shutter::Open),
        capture(&without, 0.01, Shutter::Open),
    );
    let p = &with.screen().pattern;
    let mut worst: f64 = 0.0;
    for j in 2..28 {
        for i in 2..38 {
            let (u, v) = (
                32.0 + 1.25 * (i as f64 + 0.5 - 20.0),
                24.0 + 1.25 * (j as f64 + 0.5 - 15.0),
            );
            let k = j * 40 + i;
            worst = worst.max((a[k] / b[k] - (1.0 + p.mura(u, v))).abs());
        }
    }
    assert!(worst < 3e-4, "worst {worst}");
}

// ------------------------------------------- level-dependent uniformity

#[test]
fn dark_levels_are_less_uniform() {
    // The black leak (1 % of white) glows 30 % brighter at the corners:
    // U(ℓ, p) = [(1 − b) x^γ + b (1 + 0.3 (n_x⁴ + n_y⁴)/2)] / [(1 − b) x^γ + b].
    // A 0.7 m collimator shows the whole screen to the camera: pixel (i, j)
    // sees (32 + 1.75 (i + ½ − 20), 24 + 1.75 (j + ½ − 15)).
    let f = quiet("black_nonuniformity = 0.3", "focal_length = 0.7", "");
    let u = |level: f64, i: usize, j: usize| {
        let (x, y) = (
            32.0 + 1.75 * (i as f64 + 0.5 - 20.0),
            24.0 + 1.75 * (j as f64 + 0.5 - 15.0),
        );
        let (nx, ny) = ((x - 32.0) / 32.0, (y - 24.0) / 24.0);
        let main = 0.99 * (level / 255.0).powf(2.2);
        (main + 0.01 * (1.0 + 0.15 * (nx.powi(4) + ny.powi(4)))) / (main + 0.01)
    };
    uniform(&f, 0);
    let dark = capture(&f, 1.0, Shutter::Open);
    uniform(&f, 255);
    let bright = capture(&f, 0.01, Shutter::Open);
    let (corner, centre) = ((3usize, 2usize), (20usize, 15usize));
    let k = |(i, j): (usize, usize)| j * 40 + i;
    let got = (dark[k(corner)] / dark[k(centre)]) / (bright[k(corner)] / bright[k(centre)]);
    let expected = (u(0.0, 3, 2) / u(0.0, 20, 15)) / (u(255.0, 3, 2) / u(255.0, 20, 15));
    assert!(expected > 1.15, "{expected}");
    assert!((got / expected - 1.0).abs() < 2e-3, "{got} vs {expected}");
    // The accessor agrees with the formula.
    let (x, y) = (32.0 + 1.75 * (3.5 - 20.0), 24.0 + 1.75 * (2.5 - 15.0));
    let acc = f.screen().uniformity_at(0, x, y) / f.screen().uniformity_at(255, x, y);
    assert!((acc / (u(0.0, 3, 2) / u(255.0, 3, 2)) - 1.0).abs() < 1e-9);
}

// --------------------------------------------------------------- optics

/// The collimator written out: screen (u, v) → camera tan, f = 0.5 m,
/// 0.1 mm pixels, k1, decentring p1, p2, thin prism s1…s4.
fn direct_geometry(u: f64, v: f64) -> (f64, f64) {
    let f_px = 0.5 / 1.0e-4;
    let (a, b) = ((u - 32.0) / f_px, (v - 24.0) / f_px);
    let r2 = a * a + b * b;
    let (k1, p1, p2) = (0.8, 0.2, -0.12);
    let (s1, s2, s3, s4) = (0.08, 1200.0, -0.04, -800.0);
    let k = 1.0 + k1 * r2;
    (
        a * k + 2.0 * p1 * a * b + p2 * (r2 + 2.0 * a * a) + s1 * r2 + s2 * r2 * r2,
        b * k + p1 * (r2 + 2.0 * b * b) + 2.0 * p2 * a * b + s3 * r2 + s4 * r2 * r2,
    )
}

const DISTORTED: &str =
    "k1 = 0.8\np1 = 0.2\np2 = -0.12\nthin_prism = [0.08, 1200.0, -0.04, -800.0]";

#[test]
fn collimator_decentring_and_thin_prism_follow_the_formula() {
    let f = quiet("", DISTORTED, "supersample = 5");
    for (u, v) in [(0.0, 0.0), (32.0, 24.0), (63.5, 10.25), (5.0, 47.0)] {
        let (tx, ty) = f.true_geometry(u, v);
        let (ex, ey) = direct_geometry(u, v);
        assert!(
            (tx - ex).abs() < 1e-15 && (ty - ey).abs() < 1e-15,
            "({u}, {v}): ({tx}, {ty}) vs ({ex}, {ey})"
        );
    }
    // The terms beyond the radial one move a corner by more than 0.02
    // camera px (what a calibration must see).
    let (x, y) = direct_geometry(0.0, 0.0);
    let f_px = 5000.0;
    let (a, b) = (-32.0 / f_px, -24.0 / f_px);
    let radial = 1.0 + 0.8 * (a * a + b * b);
    let shift = 4000.0 * (x - a * radial).hypot(y - b * radial);
    assert!(shift > 0.02, "{shift} px");
    // A dot is imaged where the formula says (camera ideal: 4000 px per
    // unit tan, centre (20, 15)).
    let (w, h) = (64usize, 48usize);
    for (du, dv) in [(30usize, 20usize), (40, 30), (22, 14)] {
        let frame = gaussian_dot_frame(w, h, (du, dv));
        show(&f, &frame);
        let dn = capture(&f, 0.01, Shutter::Open);
        uniform(&f, 0);
        let bg = capture(&f, 0.01, Shutter::Open);
        let (mut sx, mut sy, mut s) = (0.0, 0.0, 0.0);
        for (k, (a, b)) in dn.iter().zip(&bg).enumerate() {
            let v = a - b;
            sx += v * ((k % 40) as f64 + 0.5);
            sy += v * ((k / 40) as f64 + 0.5);
            s += v;
        }
        let (x, y) = direct_geometry(du as f64, dv as f64);
        let (pu, pv) = (4000.0 * x + 20.0, 4000.0 * y + 15.0);
        assert!(
            (sx / s - pu).abs() < 0.02 && (sy / s - pv).abs() < 0.02,
            "dot ({du}, {dv}): ({:.4}, {:.4}) vs ({pu:.4}, {pv:.4})",
            sx / s,
            sy / s
        );
    }
}

#[test]
fn a_folding_collimator_is_refused() {
    let err = keys(
        "",
        "thin_prism = [0.0, 1000.0, 0.0, 0.0]\nfocal_length = 0.05",
        "",
    )
    .try_facility()
    .err()
    .expect("refused")
    .to_string();
    assert!(err.contains("collimator.thin_prism"), "{err}");
}

#[test]
fn veiling_glare_is_a_pedestal_of_the_mean_signal() {
    // Left half white, right half black; 0.2 % glare: every pixel gains
    // 0.002 × the mean signal of the glare-free image.
    let glare = quiet("", "", "veiling_glare = 0.002");
    let clean = quiet("", "", "");
    let mut frame = vec![encode_grey(0, 8); 64 * 48];
    for y in 0..48 {
        for x in 0..32 {
            frame[y * 64 + x] = encode_grey(255, 8);
        }
    }
    for f in [&glare, &clean] {
        show(f, &frame);
    }
    let (a, b) = (
        capture(&glare, 0.01, Shutter::Open),
        capture(&clean, 0.01, Shutter::Open),
    );
    let mean = b.iter().sum::<f64>() / b.len() as f64;
    let pedestal = 0.002 * mean;
    assert!(pedestal > 10.0, "{pedestal} DN");
    for (k, (x, y)) in a.iter().zip(&b).enumerate() {
        assert!(
            (x - y - pedestal).abs() <= 1.0,
            "pixel {k}: {} vs {pedestal}",
            x - y
        );
    }
    // The mean too (rounding does not average out: a uniform screen gives
    // runs of equal fractional parts).
    let diff = a.iter().zip(&b).map(|(x, y)| x - y).sum::<f64>() / a.len() as f64;
    assert!((diff - pedestal).abs() < 0.5, "{diff} vs {pedestal}");
}

// --------------------------------------------------------------- camera

#[test]
fn non_linearity_at_half_and_full_well() {
    // e' = e (1 − β e / full_well), β = 1 %: the deficit is 0.5 % at half
    // well and 1 % at full well.
    for (exposure, fill) in [(0.5, 0.5), (1.0, 1.0)] {
        // Full well set so that the centre pixel's signal at `exposure`
        // sits at `fill` of it: its linear signal from a linear twin.
        let linear = quiet("", "", "");
        uniform(&linear, 255);
        let e_lin = capture(&linear, exposure * 0.01, Shutter::Open)[15 * 40 + 20] / 0.05;
        let fw = e_lin / fill * 1.0001;
        let f = quiet("", "", &format!("nonlinearity = 0.01\nfull_well = {fw:e}"));
        uniform(&f, 255);
        let got = capture(&f, exposure * 0.01, Shutter::Open)[15 * 40 + 20] / 0.05;
        let deficit = 1.0 - got / e_lin;
        let expected = 0.01 * e_lin / fw;
        assert!(
            (deficit - expected).abs() < 1e-4,
            "fill {fill}: deficit {deficit}, formula {expected}"
        );
    }
}

#[test]
fn dark_frames_have_bias_dark_current_row_and_read_noise() {
    // gain 1 DN/e⁻, bias 100 DN, dark 1000 e⁻/s over 10 ms (10 e⁻), read
    // noise 3 e⁻, row noise 5 e⁻; the screen at full white with glare on
    // (no light reaches a closed shutter).
    let f = keys(
        "",
        "",
        "bias_dn = 100.0\ndark_current = 1000.0\nread_noise = 3.0\nrow_noise = 5.0\nveiling_glare = 0.01\n\
         gain = 1.0",
    )
    .facility();
    uniform(&f, 255);
    let (w, h, frames) = (40usize, 30usize, 300usize);
    let (mut sum, mut n) = (0.0, 0.0);
    let (mut row_means, mut within) = (Vec::new(), Vec::new());
    for _ in 0..frames {
        let d = capture(&f, 0.01, Shutter::Closed);
        for j in 0..h {
            let row = &d[j * w..(j + 1) * w];
            let m = row.iter().sum::<f64>() / w as f64;
            row_means.push(m);
            within.extend(row.iter().map(|v| v - m));
            sum += row.iter().sum::<f64>();
            n += w as f64;
        }
    }
    let mean = sum / n;
    assert!((mean - 110.0).abs() < 0.05, "mean {mean} DN");
    let var = |v: &[f64]| {
        let m = v.iter().sum::<f64>() / v.len() as f64;
        v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64
    };
    // Pixel noise: Poisson dark (10) + read (9) + quantisation (1/12).
    let pixel = 10.0 + 9.0 + 1.0 / 12.0;
    let expected_rows = 25.0 + pixel / w as f64;
    let got_rows = var(&row_means);
    assert!(
        (got_rows / expected_rows - 1.0).abs() < 0.08,
        "row-mean variance {got_rows}, formula {expected_rows}"
    );
    let expected_within = pixel * (w as f64 - 1.0) / w as f64;
    let got_within = var(&within);
    assert!(
        (got_within / expected_within - 1.0).abs() < 0.03,
        "within-row variance {got_within}, formula {expected_within}"
    );
}
