//! The camera's optics against references written here: a PSF kernel's
//! encircled energy against the Airy and Gaussian closed forms, a point
//! source's pixel values against the Gaussian's exact pixel integrals
//! (products of error functions), and a grid of spots through a
//! Brown–Conrady lens against OpenCV's distortion formula.

use optistim::instruments::intrinsics::CameraIntrinsics;
use optistim::optics::distortion::resample_radiance;
use optistim::optics::psf::{kernel, Psf, ENCLOSED};
use optistim::scene::camera::Pinhole;

/// Encircled energy of the convolved image of a point source at a pixel
/// centre, summed over the pixels whose centres lie within r, against the
/// closed form at the radius of the same area (the pixels' own extent
/// blurs the edge by at most a pixel: compared at r ≥ 4 px).
fn encircled(img: &[f32], n: usize, r: f64) -> f64 {
    let c = (n / 2) as f64;
    let mut s = 0.0;
    for y in 0..n {
        for x in 0..n {
            if ((x as f64 - c).powi(2) + (y as f64 - c).powi(2)).sqrt() <= r {
                s += img[y * n + x] as f64;
            }
        }
    }
    s
}

#[test]
fn airy_encircled_energy_matches_the_closed_form() {
    // f/8 at 700 nm on 2.2 µm pixels: λN = 2.55 px, first dark ring at 3.1 px.
    let psf = Psf::Airy {
        f_number: 8.0,
        wavelength_m: 700e-9,
        pitch_m: 2.2e-6,
    };
    let s = 700e-9 * 8.0 / 2.2e-6;
    let n = 257;
    let mut img = vec![0.0f32; n * n];
    img[(n / 2) * n + n / 2] = 1.0;
    let out = kernel(&psf).unwrap().convolve(&img, n, n);
    let total: f64 = out.iter().map(|&v| v as f64).sum();
    assert!((total - 1.0).abs() < 1e-5, "total {total}");
    for r in [4.0, 6.0, 8.0, 12.0, 20.0] {
        // The closed form, written here: 1 − J0² − J1² at x = π r / (λN);
        // the pixel sum's radius is that of the same area (count × 1 px²).
        let mut count = 0usize;
        let c = (n / 2) as f64;
        for y in 0..n {
            for x in 0..n {
                count += usize::from(((x as f64 - c).powi(2) + (y as f64 - c).powi(2)).sqrt() <= r);
            }
        }
        let r_eq = (count as f64 / std::f64::consts::PI).sqrt();
        let x = std::f64::consts::PI * r_eq / s;
        // The kernel is cut at ENCLOSED and renormalised.
        let exact = ((1.0 - libm::j0(x).powi(2) - libm::j1(x).powi(2)) / ENCLOSED).min(1.0);
        let got = encircled(&out, n, r);
        println!("r = {r} px: kernel {got:.4}, closed form {exact:.4}");
        assert!(
            (got - exact).abs() < 0.003,
            "r = {r} px: kernel {got:.4} against closed form {exact:.4}"
        );
    }
}

#[test]
fn gaussian_pixels_are_the_exact_integrals() {
    let sigma = 0.8;
    let k = kernel(&Psf::Gaussian { sigma_px: sigma }).unwrap();
    let n = 2 * k.half + 1;
    let phi = |x: f64| 0.5 * libm::erfc(-x / (sigma * std::f64::consts::SQRT_2));
    let span = |c: f64| phi(c + 0.5) - phi(c - 0.5);
    // Renormalised over the kernel's square.
    let total: f64 = (0..n)
        .map(|i| span(i as f64 - k.half as f64))
        .sum::<f64>()
        .powi(2);
    for j in 0..n {
        for i in 0..n {
            let (di, dj) = (i as f64 - k.half as f64, j as f64 - k.half as f64);
            let exact = span(di) * span(dj) / total;
            assert!((k.weights[j * n + i] - exact).abs() < 1e-12);
        }
    }
    // And its encircled energy by radius against 1 − exp(−r²/2σ²).
    assert!(
        (Psf::Gaussian { sigma_px: sigma }.encircled_energy(sigma) - (1.0 - (-0.5f64).exp())).abs()
            < 1e-15
    );
}

/// OpenCV's distortion of normalised coordinates, written here.
fn opencv_distort(x: f64, y: f64, d: [f64; 5]) -> (f64, f64) {
    let [k1, k2, p1, p2, k3] = d;
    let r2 = x * x + y * y;
    let radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
    (
        x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
        y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
    )
}

#[test]
fn a_grid_of_spots_lands_where_opencv_puts_it() {
    let (w, h) = (160usize, 120usize);
    let f = 150.0;
    let d = [-0.18, 0.04, 0.002, -0.0015, 0.0];
    let lens = CameraIntrinsics {
        width: w,
        height: h,
        camera_matrix: [[f, 0.0, 79.2], [0.0, f, 59.7], [0.0, 0.0, 1.0]],
        distortion: d,
    };
    // The ideal image: twice the field at the same focal length, spots of
    // σ = 1.2 px on a grid of normalised positions.
    let ideal = Pinhole {
        width: 2 * w,
        height: 2 * h,
        fx: f,
        fy: f,
        cx: w as f64,
        cy: h as f64,
    };
    let sigma = 1.2;
    let mut spots = Vec::new();
    for gy in -2..=2 {
        for gx in -3..=3 {
            spots.push((gx as f64 * 0.14, gy as f64 * 0.14));
        }
    }
    let mut img = vec![0.0f32; ideal.width * ideal.height];
    for (y, row) in img.chunks_mut(ideal.width).enumerate() {
        for (x, v) in row.iter_mut().enumerate() {
            let (u, vv) = (x as f64 + 0.5, y as f64 + 0.5);
            for &(sx, sy) in &spots {
                let (cu, cv) = (f * sx + ideal.cx, f * sy + ideal.cy);
                *v +=
                    (-((u - cu).powi(2) + (vv - cv).powi(2)) / (2.0 * sigma * sigma)).exp() as f32;
            }
        }
    }
    let out = resample_radiance(&img, &ideal, &lens, 4).unwrap();
    let mut worst = 0.0f64;
    for &(sx, sy) in &spots {
        let (xd, yd) = opencv_distort(sx, sy, d);
        // OpenCV's pixel (centres at integers) + 0.5: this crate's convention.
        let (pu, pv) = (f * xd + 79.2 + 0.5, f * yd + 59.7 + 0.5);
        // Centroid over a 13 px box around the expected position.
        let (mut m, mut mx, mut my) = (0.0, 0.0, 0.0);
        for y in (pv as isize - 6)..=(pv as isize + 6) {
            for x in (pu as isize - 6)..=(pu as isize + 6) {
                if x < 0 || y < 0 || x >= w as isize || y >= h as isize {
                    continue;
                }
                let v = out[y as usize * w + x as usize] as f64;
                m += v;
                mx += v * (x as f64 + 0.5);
                my += v * (y as f64 + 0.5);
            }
        }
        let (cu, cv) = (mx / m, my / m);
        worst = worst.max((cu - pu).hypot(cv - pv));
    }
    println!("worst spot offset {worst:.4} px");
    assert!(worst < 0.03, "worst spot offset {worst} px");
}
