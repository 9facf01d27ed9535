//! The whole AMIE validation pipeline (render, background, NCC, SSIM) on
//! both flight images, against the reference paper's numbers.

use optistim::validate::compare::{self, ValidationOptions, ValidationReport};

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/data");
const IMG1: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/data/amie/AMI_EE3_040819_00208_00030.IMG");
const IMG2: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/data/amie/AMI_EE3_041028_00101_00010.IMG");

fn run(img: &str, model: &str) -> ValidationReport {
    let r = compare::validate_amie(img, model, &ValidationOptions::new(DATA)).unwrap();
    println!(
        "{} {model}: shift ({:.2}, {:.2}) px, l {:.5} c {:.5} s {:.5} ssim {:.5}; unnormalised l {:.5} ssim {:.5}; real/render {:.4}; ncc {:.4}; no-floor l {:.5} c {:.5} s {:.5}",
        r.product_id, r.alignment.dx, r.alignment.dy, r.ssim.luminance, r.ssim.contrast, r.ssim.structure, r.ssim.mssim,
        r.ssim_unnormalised.luminance, r.ssim_unnormalised.mssim, r.total_signal_ratio, r.alignment.peak_ncc, r.ssim_without_noise_floor.luminance, r.ssim_without_noise_floor.contrast, r.ssim_without_noise_floor.structure
    );
    r
}

#[test]
fn explore() {
    for img in [IMG1, IMG2] {
        for m in ["lambert", "oren_nayar", "hapke"] {
            match compare::validate_amie(img, m, &ValidationOptions::new(DATA)) {
                Ok(_) => { let r = compare::run(img, m, &ValidationOptions::new(DATA)).unwrap(); compare::write_outputs(&r, format!("/tmp/val2/{}_{m}", r.report.product_id)).unwrap(); run(img, m); }
                Err(e) => println!("{m}: {e}"),
            }
        }
    }
}
