//! NCC alignment on synthetic images shifted by known amounts.

use optistim::validate::align::{ncc_align, ncc_at, shift_bilinear};
use optistim::validate::Raster;

/// A smooth synthetic scene (a few Gaussian blobs and a soft-edged disk)
/// evaluated at continuous coordinates, so shifted copies are exact.
fn scene(x: f64, y: f64) -> f32 {
    let blobs = [
        (40.0, 50.0, 5.0, 200.0),
        (80.0, 30.0, 3.0, 150.0),
        (70.0, 90.0, 7.0, 120.0),
        (25.0, 100.0, 4.0, 90.0),
    ];
    let mut v = 20.0;
    for (cx, cy, s, a) in blobs {
        v += a * (-((x - cx).powi(2) + (y - cy).powi(2)) / (2.0 * s * s)).exp();
    }
    let r = ((x - 64.0).powi(2) + (y - 64.0).powi(2)).sqrt();
    v += 100.0 / (1.0 + ((r - 25.0) / 1.5).exp());
    v as f32
}

fn render(dx: f64, dy: f64) -> Raster {
    Raster::from_fn(128, 128, |c, r| {
        scene(c as f64 + 0.5 - dx, r as f64 + 0.5 - dy)
    })
}

#[test]
fn recovers_integer_shifts_exactly() {
    let reference = render(0.0, 0.0);
    for (dx, dy) in [(0, 0), (3, -2), (-7, 5), (10, 10), (-12, 0)] {
        let moving = render(dx as f64, dy as f64);
        let a = ncc_align(&reference, &moving, 15).unwrap();
        assert_eq!(a.integer_shift, (dx, dy));
        assert!(
            (a.dx - dx as f64).abs() < 0.05 && (a.dy - dy as f64).abs() < 0.05,
            "{a:?}"
        );
        assert!(a.peak_ncc > 0.999);
    }
}

#[test]
fn recovers_subpixel_shifts() {
    let reference = render(0.0, 0.0);
    for (dx, dy) in [(2.3, -1.6), (-4.5, 0.25), (0.4, 6.8), (-9.7, -3.35)] {
        let moving = render(dx, dy);
        let a = ncc_align(&reference, &moving, 12).unwrap();
        println!("true ({dx}, {dy}) found ({:.3}, {:.3})", a.dx, a.dy);
        // Parabolic refinement of a smooth correlation peak: bias < 0.15 px.
        assert!(
            (a.dx - dx).abs() < 0.15 && (a.dy - dy).abs() < 0.15,
            "{a:?}"
        );
    }
}

#[test]
fn shift_bilinear_undoes_the_shift() {
    let reference = render(0.0, 0.0);
    let moving = render(3.0, -2.0);
    let back = shift_bilinear(&moving, -3.0, 2.0, 20.0);
    // Integer shift: exact away from the borders.
    for r in 10..118 {
        for c in 10..118 {
            assert!((back.get(c, r) - reference.get(c, r)).abs() < 1e-4);
        }
    }
    let a = ncc_align(&reference, &shift_bilinear(&moving, -2.5, 2.5, 20.0), 5).unwrap();
    assert!(
        (a.dx - 0.5).abs() < 0.15 && (a.dy - 0.5).abs() < 0.15,
        "{a:?}"
    );
}

#[test]
fn ncc_properties() {
    let a = render(0.0, 0.0);
    // Invariant to gain and offset.
    let b = Raster::from_fn(128, 128, |c, r| 3.0 * a.get(c, r) + 50.0);
    assert!((ncc_at(&a, &b, 0, 0) - 1.0).abs() < 1e-9);
    let neg = Raster::from_fn(128, 128, |c, r| -a.get(c, r));
    assert!((ncc_at(&a, &neg, 0, 0) + 1.0).abs() < 1e-9);
    assert_eq!(ncc_at(&a, &Raster::filled(128, 128, 1.0), 0, 0), 0.0);
    assert!(ncc_align(&a, &Raster::filled(64, 64, 0.0), 3).is_err());
    assert!(ncc_align(&a, &a, 100).is_err());
}
