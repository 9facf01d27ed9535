//! SSIM (Wang et al. 2004) against closed forms, a slow direct
//! implementation and reference numbers from scikit-image.
#![allow(clippy::needless_range_loop)]

use optistim::validate::ssim::{self, ssim};
use optistim::validate::Raster;

/// Deterministic test pair, integer-valued (exact in f32 and f64).
fn pair() -> (Raster, Raster) {
    let a = Raster::from_fn(32, 24, |x, y| {
        let (xf, yf) = (x as f64, y as f64);
        (100.0 + 80.0 * (0.3 * xf).sin() * (0.2 * yf).cos() + 10.0 * ((x * 7 + y * 13) % 11) as f64)
            .round() as f32
    });
    let b = Raster::from_fn(32, 24, |x, y| {
        let (xf, yf) = (x as f64, y as f64);
        let av = a.get(x, y) as f64;
        (0.9 * av + 20.0 + 15.0 * (0.5 * xf + 0.1 * yf).cos() + 5.0 * ((x * 3 + y * 5) % 7) as f64)
            .round() as f32
    });
    (a, b)
}

#[test]
fn matches_scikit_image() {
    // Computed with scikit-image 0.26.0 / numpy 2.4.6:
    //   x, y = np.meshgrid(np.arange(32), np.arange(24))
    //   a = np.round(100 + 80*np.sin(0.3*x)*np.cos(0.2*y) + 10*((x*7 + y*13) % 11))
    //   b = np.round(0.9*a + 20 + 15*np.cos(0.5*x + 0.1*y) + 5*((x*3 + y*5) % 7))
    //   m, S = structural_similarity(a, b, gaussian_weights=True, sigma=1.5,
    //            use_sample_covariance=False, data_range=L, full=True)
    // skimage averages S over the interior that excludes 5 px on each side,
    // which is exactly the "valid" map of Wang's ssim_index.m.
    let (a, b) = pair();
    for (l, mean, s55, s12_20) in [
        (
            255.0,
            0.9221357419802165,
            0.9344618722683239,
            0.8950083982536848,
        ),
        (
            1023.0,
            0.9385786875817095,
            0.9514021884559227,
            0.9202630772832634,
        ),
    ] {
        let r = ssim(&a, &b, l).unwrap();
        assert!((r.mssim - mean).abs() < 1e-9, "{} vs {mean}", r.mssim);
        assert_eq!((r.map.width, r.map.height), (22, 14));
        assert!((r.map.get(0, 0) as f64 - s55).abs() < 1e-6);
        assert!((r.map.get(15, 7) as f64 - s12_20).abs() < 1e-6);
    }
}

/// Straightforward O(N·121) SSIM with an explicitly built 2-D window.
fn direct(a: &Raster, b: &Raster, l: f64) -> (Vec<f64>, Vec<[f64; 3]>) {
    let (c1, c2) = ((0.01 * l).powi(2), (0.03 * l).powi(2));
    let mut w = [[0.0f64; 11]; 11];
    let mut tot = 0.0;
    for (i, row) in w.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            let (di, dj) = (i as f64 - 5.0, j as f64 - 5.0);
            *v = (-(di * di + dj * dj) / (2.0 * 1.5 * 1.5)).exp();
            tot += *v;
        }
    }
    let mut maps = vec![];
    let mut comps = vec![];
    for r in 0..a.height - 10 {
        for c in 0..a.width - 10 {
            let (mut mx, mut my) = (0.0, 0.0);
            for i in 0..11 {
                for j in 0..11 {
                    let wt = w[i][j] / tot;
                    mx += wt * a.get(c + j, r + i) as f64;
                    my += wt * b.get(c + j, r + i) as f64;
                }
            }
            let (mut vx, mut vy, mut cxy) = (0.0, 0.0, 0.0);
            for i in 0..11 {
                for j in 0..11 {
                    let wt = w[i][j] / tot;
                    let (dx, dy) = (
                        a.get(c + j, r + i) as f64 - mx,
                        b.get(c + j, r + i) as f64 - my,
                    );
                    vx += wt * dx * dx;
                    vy += wt * dy * dy;
                    cxy += wt * dx * dy;
                }
            }
            maps.push(
                ((2.0 * mx * my + c1) * (2.0 * cxy + c2))
                    / ((mx * mx + my * my + c1) * (vx + vy + c2)),
            );
            let (sx, sy) = (vx.sqrt(), vy.sqrt());
            comps.push([
                (2.0 * mx * my + c1) / (mx * mx + my * my + c1),
                (2.0 * sx * sy + c2) / (vx + vy + c2),
                (cxy + c2 / 2.0) / (sx * sy + c2 / 2.0),
            ]);
        }
    }
    (maps, comps)
}

#[test]
fn matches_direct_implementation() {
    let (a, b) = pair();
    let r = ssim(&a, &b, 255.0).unwrap();
    let (map, comps) = direct(&a, &b, 255.0);
    for (i, v) in map.iter().enumerate() {
        assert!((r.map.data[i] as f64 - v).abs() < 1e-6);
        // l*c*s equals the SSIM map when C3 = C2/2.
        let p = comps[i][0] * comps[i][1] * comps[i][2];
        assert!((p - v).abs() < 1e-12);
    }
    let n = comps.len() as f64;
    let mean = |k: usize| comps.iter().map(|c| c[k]).sum::<f64>() / n;
    assert!((r.luminance - mean(0)).abs() < 1e-9);
    assert!((r.contrast - mean(1)).abs() < 1e-9);
    assert!((r.structure - mean(2)).abs() < 1e-9);
    assert!((r.mssim - map.iter().sum::<f64>() / n).abs() < 1e-9);
}

#[test]
fn identical_images_give_one() {
    let (a, _) = pair();
    let r = ssim(&a, &a, 1023.0).unwrap();
    for v in [r.mssim, r.luminance, r.contrast, r.structure] {
        assert!((v - 1.0).abs() < 1e-12, "{v}");
    }
    // Also for a flat image (all variances 0).
    let f = Raster::filled(20, 20, 7.0);
    assert!((ssim(&f, &f, 1023.0).unwrap().mssim - 1.0).abs() < 1e-12);
}

#[test]
fn constant_shift_changes_only_luminance() {
    let l = 1023.0;
    let c1 = (ssim::K1 * l).powi(2);
    // Flat image mu, shifted by delta: l = 1 - delta^2 / (mu^2 + (mu+delta)^2 + C1), c = s = 1.
    for (mu, delta) in [(100.0f64, 10.0f64), (40.0, 25.0), (500.0, -100.0)] {
        let a = Raster::filled(30, 30, mu as f32);
        let b = Raster::filled(30, 30, (mu + delta) as f32);
        let r = ssim(&a, &b, l).unwrap();
        let expect = 1.0 - delta * delta / (mu * mu + (mu + delta).powi(2) + c1);
        assert!(
            (r.luminance - expect).abs() < 1e-9,
            "{} vs {expect}",
            r.luminance
        );
        assert!((r.contrast - 1.0).abs() < 1e-12 && (r.structure - 1.0).abs() < 1e-12);
        assert!((r.mssim - expect).abs() < 1e-9);
    }
    // Textured image: contrast and structure stay exactly 1; luminance
    // follows the closed form with the local means.
    let (a, _) = pair();
    let delta = 30.0;
    let b = Raster::from_fn(a.width, a.height, |x, y| a.get(x, y) + delta as f32);
    let r = ssim(&a, &b, l).unwrap();
    assert!(
        (r.contrast - 1.0).abs() < 1e-9 && (r.structure - 1.0).abs() < 1e-9,
        "{} {}",
        r.contrast,
        r.structure
    );
    assert!(r.luminance < 1.0);
    let (_, comps) = direct(&a, &b, l);
    for (i, c) in comps.iter().enumerate() {
        assert!((r.luminance_map.data[i] as f64 - c[0]).abs() < 1e-6);
    }
}

#[test]
fn rejects_bad_inputs() {
    let a = Raster::filled(10, 30, 1.0);
    assert!(ssim(&a, &a, 1.0).is_err()); // smaller than the window
    let b = Raster::filled(20, 20, 1.0);
    let c = Raster::filled(21, 20, 1.0);
    assert!(ssim(&b, &c, 1.0).is_err());
    assert!(ssim(&b, &b, 0.0).is_err());
}
