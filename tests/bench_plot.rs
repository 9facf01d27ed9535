//! `optistim bench --plot`: the speed-against-error figure is written where
//! asked (a directory or a .png path), at its documented size, with one
//! coloured curve per setting family and the targets drawn.

use std::path::Path;
use std::process::Command;

/// The figure's documented size (`bench --help`, BENCHMARKS.md).
const SIZE: (u32, u32) = (1400, 620);
/// The first two series colours of `optistim::figures::PALETTE`.
const BLUE: [u8; 3] = [0, 114, 178];
const ORANGE: [u8; 3] = [213, 94, 0];

/// The benchmark Moon at 192×192 px, so a sweep takes about a second.
fn small_scene(dir: &Path) -> std::path::PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("configs/moon_bench.toml")).unwrap();
    let data = root.join("data");
    let text = text
        .replace("[1024, 1024]", "[192, 192]")
        .replace("../data", data.to_str().unwrap());
    assert!(text.contains("[192, 192]"));
    let path = dir.join("scene.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn bench(scene: &Path, plot: &Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_optistim"))
        .arg("bench")
        .arg("--scene")
        .arg(scene)
        .args(["--phases", "60", "--densities", "0.5,1", "--repeats", "1"])
        .args(["--interior", "pixels,caps", "--plot"])
        .arg(plot)
        .output()
        .unwrap()
}

fn count(img: &image::RgbImage, colour: [u8; 3]) -> usize {
    img.pixels().filter(|p| p.0 == colour).count()
}

fn check_figure(png: &Path) {
    if let Some(k) = std::env::var_os("OPTISTIM_KEEP_FIGURES") {
        std::fs::copy(png, Path::new(&k).join(png.file_name().unwrap())).unwrap();
    }
    let img = image::open(png).unwrap().to_rgb8();
    assert_eq!((img.width(), img.height()), SIZE);
    let dark = img
        .pixels()
        .filter(|p| p.0.iter().all(|&c| c < 100))
        .count();
    assert!(dark > 3000, "only {dark} dark pixels (text, axes, targets)");
    // Two families (interior pixels, interior caps), each a curve with
    // points in both panels: far more than their legend swatches.
    for c in [BLUE, ORANGE] {
        assert!(count(&img, c) > 400, "{c:?}: {} pixels", count(&img, c));
    }
}

#[test]
fn bench_plot_into_a_directory_and_to_a_png_path() {
    let dir = tempfile::tempdir().unwrap();
    let scene = small_scene(dir.path());
    let out = dir.path().join("figs");
    let res = bench(&scene, &out);
    assert!(
        res.status.success(),
        "{}",
        String::from_utf8_lossy(&res.stderr)
    );
    check_figure(&out.join("bench.png"));

    let png = dir.path().join("deeper/speed.png");
    let res = bench(&scene, &png);
    assert!(res.status.success());
    check_figure(&png);
}
