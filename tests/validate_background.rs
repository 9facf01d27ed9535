//! Background removal on a synthetic frame with known dark ramp and halo,
//! and on the two real AMIE frames.

mod common;
use common::{IMG1, IMG2};
use optistim::validate::amie;
use optistim::validate::background::{remove_background, BackgroundParams, Disk};
use optistim::validate::Raster;

/// Deterministic pseudo-random noise in [-1, 1).
fn noise(i: usize) -> f64 {
    let mut z = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0xD1B5_4A32_D192_ED03;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

#[test]
fn synthetic_ramp_halo_and_disk() {
    let disk = Disk {
        cx: 250.0,
        cy: 240.0,
        radius: 90.0,
    };
    let ramp = |x: f64, y: f64| 30.0 + 18.0 * y / 512.0 + 3.0 * (x / 512.0 - 0.5).powi(2);
    let halo = |d: f64| if d < 0.0 { 6.0 } else { 6.0 * (-d / 8.0).exp() };
    let moon = |x: f64, y: f64| {
        if disk.limb_distance(x, y) < 0.0 {
            300.0 + 100.0 * ((x - 250.0) / 90.0)
        } else {
            0.0
        }
    };
    let img = Raster::from_fn(512, 512, |c, r| {
        let (x, y) = (c as f64 + 0.5, r as f64 + 0.5);
        let mut v =
            ramp(x, y) + halo(disk.limb_distance(x, y)) + moon(x, y) + 2.0 * noise(r * 512 + c);
        if (r * 7 + c * 13) % 997 == 0 {
            v += 400.0; // "stars" / hits, to be clipped
        }
        v.round() as f32
    });
    let (clean, model) = remove_background(&img, disk, &BackgroundParams::amie()).unwrap();
    println!(
        "dark {:.2} sigma {:.2} halo {:?}",
        model.dark_level_dn, model.sky_sigma_dn, model.halo
    );
    // Polynomial recovers the ramp to < 0.3 DN far from the disk.
    for &(x, y) in &[(20.0, 20.0), (500.0, 30.0), (30.0, 490.0), (480.0, 480.0)] {
        assert!(
            (model.at(x, y) - ramp(x, y)).abs() < 0.4,
            "{} vs {}",
            model.at(x, y),
            ramp(x, y)
        );
    }
    // Halo at the limb within 1.5 DN of the truth (it is binned).
    assert!(
        (model.halo_at(0.0) - halo(1.5)).abs() < 1.5,
        "{}",
        model.halo_at(0.0)
    );
    // Inside the disk the Moon comes back within a couple of DN.
    let mut worst = 0.0f64;
    for r in 200..280 {
        for c in 200..300 {
            if (r * 7 + c * 13) % 997 == 0 {
                continue;
            }
            let (x, y) = (c as f64 + 0.5, r as f64 + 0.5);
            worst = worst.max((clean.get(c, r) as f64 - moon(x, y)).abs());
        }
    }
    assert!(worst < 5.0, "{worst}");
    // Sky is ~0 and never negative.
    assert!(clean.data.iter().all(|&v| v >= 0.0));
    let sky_mean: f64 = (0..60)
        .flat_map(|r| (0..512).map(move |c| (c, r)))
        .map(|(c, r)| clean.get(c, r) as f64)
        .sum::<f64>()
        / (60.0 * 512.0);
    assert!(sky_mean < 1.5, "{sky_mean}");
}

fn disk_of(o: &amie::AmieObservation) -> Disk {
    let (c, r) = o.scene.moon_disk_px().unwrap();
    Disk {
        cx: c[0],
        cy: c[1],
        radius: r,
    }
}

#[test]
fn real_frames() {
    for (p, lit_min) in [(IMG1, 700.0f32), (IMG2, 40.0)] {
        let o = amie::load(p).unwrap();
        // The predicted disk is off by ~6 px on image 1 before alignment, so
        // widen it a little here (the glue uses the aligned disk).
        let mut disk = disk_of(&o);
        disk.radius += 6.0;
        let (clean, m) = remove_background(&o.image, disk, &BackgroundParams::amie()).unwrap();
        println!(
            "{}: dark {:.1} DN, sky sigma {:.2} DN, poly {:.2?}, halo {:.2?}",
            o.scene.label.product_id, m.dark_level_dn, m.sky_sigma_dn, m.poly, m.halo
        );
        assert!((25.0..90.0).contains(&m.dark_level_dn));
        // After removal the sky is flat around 0: median ~0, 95th pct within 3 sigma.
        let mut sky: Vec<f32> = vec![];
        for r in 0..512 {
            for c in 0..512 {
                if disk.limb_distance(c as f64 + 0.5, r as f64 + 0.5) > 30.0
                    && o.image.get(c, r) < 1023.0
                {
                    sky.push(clean.get(c, r));
                }
            }
        }
        sky.sort_by(|a, b| a.total_cmp(b));
        let med = sky[sky.len() / 2];
        let p95 = sky[sky.len() * 95 / 100];
        println!("  cleaned sky median {med}, p95 {p95}");
        assert!(med < 1.0 && (p95 as f64) < 3.5 * m.sky_sigma_dn + 1.0);
        // The Moon survives.
        let max = clean
            .data
            .iter()
            .zip(&o.image.data)
            .filter(|(_, &v)| v < 1023.0)
            .map(|(c, _)| *c)
            .fold(0.0f32, f32::max);
        assert!(max > lit_min, "{max}");
    }
}

#[test]
fn too_few_sky_pixels() {
    let img = Raster::filled(64, 64, 10.0);
    let disk = Disk {
        cx: 32.0,
        cy: 32.0,
        radius: 100.0,
    };
    assert!(remove_background(&img, disk, &BackgroundParams::amie()).is_err());
}
