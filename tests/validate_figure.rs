//! `validate amie` figures: `comparison.png` (four labelled panels around
//! the disk with colour bars and the numbers) and `profile.png` are
//! produced at their sizes and show what they claim: the crop, the
//! diverging difference, and the profile direction.

use std::path::Path;

use optistim::validate::background::Disk;
use optistim::validate::figure::{self, Comparison, COMPARISON_SIZE, PROFILE_SIZE};
use optistim::validate::ssim::ssim;
use optistim::validate::Raster;

/// A 200×160 frame with a disk of radius 30 at (80.5, 90.5), lit on its
/// right half (x > cx), 1000 DN; the render is 100 DN darker on the
/// upper lit quarter.
fn pair() -> (Raster, Raster, Disk) {
    let disk = Disk {
        cx: 80.5,
        cy: 90.5,
        radius: 30.0,
    };
    let lit = |c: usize, r: usize| {
        let (x, y) = (c as f64 + 0.5, r as f64 + 0.5);
        disk.limb_distance(x, y) <= 0.0 && x > disk.cx
    };
    let real = Raster::from_fn(200, 160, |c, r| if lit(c, r) { 1000.0 } else { 0.0 });
    let render = Raster::from_fn(200, 160, |c, r| {
        match (lit(c, r), r as f64 + 0.5 < disk.cy) {
            (true, true) => 900.0,
            (true, false) => 1000.0,
            _ => 0.0,
        }
    });
    (real, render, disk)
}

fn keep(p: &Path) {
    if let Some(k) = std::env::var_os("OPTISTIM_KEEP_FIGURES") {
        std::fs::copy(p, Path::new(&k).join(p.file_name().unwrap())).unwrap();
    }
}

fn count(img: &image::RgbImage, f: impl Fn([u8; 3]) -> bool) -> usize {
    img.pixels().filter(|p| f(p.0)).count()
}

#[test]
fn comparison_and_profile_are_drawn_at_their_sizes() {
    let (real, render, disk) = pair();
    let s = ssim(&real, &render, 1000.0).unwrap();
    let cmp = Comparison {
        real: &real,
        render: &render,
        ssim: &s,
        disk,
        title: "synthetic, model test".into(),
        notes: vec!["SSIM full frame: 0.9".into(), "shift (0, 0) px".into()],
    };
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("comparison.png");
    figure::write_comparison_png(&p, &cmp).unwrap();
    keep(&p);
    let img = image::open(&p).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), COMPARISON_SIZE);
    // Text and axes drawn; the real − render > 0 region red (of the
    // diverging map: R high, G and B low), and no blue (no negative diff).
    assert!(count(&img, |c| c.iter().all(|&v| v < 60)) > 5000);
    let red = count(&img, |c| c[0] > 150 && c[1] < 60 && c[2] < 70);
    assert!(red > 2000, "{red} red pixels");
    let p = dir.path().join("profile.png");
    figure::write_profile_png(&p, &cmp).unwrap();
    keep(&p);
    let img = image::open(&p).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), PROFILE_SIZE);
    assert!(count(&img, |c| c.iter().all(|&v| v < 100)) > 1000);
}

#[test]
fn crop_holds_the_disk_and_margin_inside_the_image() {
    let (x0, x1, y0, y1) = figure::crop(
        &Disk {
            cx: 80.5,
            cy: 90.5,
            radius: 30.0,
        },
        200,
        160,
    );
    // Half side: 30 × 1.25 + 2 = 39.5 px.
    assert_eq!((x0, x1, y0, y1), (41, 120, 51, 130));
    // A disk running off the frame is clipped to it.
    let c = figure::crop(
        &Disk {
            cx: 5.0,
            cy: 150.0,
            radius: 30.0,
        },
        200,
        160,
    );
    assert_eq!((c.0, c.3), (0, 160));
}

#[test]
fn profile_points_to_the_lit_side_and_sizes_are_checked() {
    let (real, render, disk) = pair();
    let (dx, dy) = figure::lit_direction(&real, &disk);
    assert!(dx > 0.999 && dy.abs() < 0.03, "({dx}, {dy})");
    let s = ssim(&real, &render, 1000.0).unwrap();
    let small = Raster::filled(20, 20, 0.0);
    let bad = Comparison {
        real: &small,
        render: &small,
        ssim: &s,
        disk,
        title: String::new(),
        notes: vec![],
    };
    let dir = tempfile::tempdir().unwrap();
    assert!(figure::write_comparison_png(dir.path().join("x.png"), &bad).is_err());
}

/// The figures of a real run (`validate amie` on the paper's AMIE image):
/// both PNGs at their sizes, with the four panels' colours present.
#[test]
fn outputs_of_a_real_validation() {
    use optistim::validate::compare::{self, ValidationOptions};
    let root = env!("CARGO_MANIFEST_DIR");
    let img = format!("{root}/data/amie/AMI_EE3_040819_00208_00030.IMG");
    let run = compare::run(
        &img,
        "oren_nayar",
        &ValidationOptions::new(format!("{root}/data")),
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    compare::write_outputs(&run, dir.path()).unwrap();
    for (name, size) in [
        ("comparison.png", COMPARISON_SIZE),
        ("profile.png", PROFILE_SIZE),
    ] {
        let p = dir.path().join(name);
        assert!(std::fs::metadata(&p).unwrap().len() > 10_000, "{name}");
        let img = image::open(&p).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), size, "{name}");
    }
    let img = image::open(dir.path().join("comparison.png"))
        .unwrap()
        .to_rgb8();
    // The SSIM map's viridis yellow (sky, SSIM 1) and the difference's
    // red and blue all appear.
    assert!(count(&img, |c| c[0] > 240 && c[1] > 220 && c[2] < 60) > 10_000);
    assert!(count(&img, |c| c[0] > 150 && c[1] < 80 && c[2] < 90) > 100);
    assert!(count(&img, |c| c[2] > 150 && c[0] < 80) > 100);
    assert!(dir.path().join("report.json").exists());
}
