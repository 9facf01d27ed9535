//! Builds the simulated facility of a config, shows a uniform grey level,
//! captures it with the simulated camera and writes the 16-bit PNG,
//! printing the time each step takes.
//!
//! cargo run --release --example simfacility_capture -- configs/simfacility.toml 128 out/capture.png

use std::time::Instant;

use optistim::facility::display::Display;
use optistim::facility::lut::encode_grey;
use optistim::instruments::{Camera, CaptureRequest, SpotMeter};
use optistim::simfacility::{write_png16, SimFacility};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let config = args
        .get(1)
        .map_or("configs/simfacility.toml", |s| s.as_str());
    let level: u32 = args.get(2).map_or(Ok(128), |s| s.parse())?;
    let out = args.get(3).map_or("out/capture.png", |s| s.as_str());
    let t = Instant::now();
    let facility = SimFacility::load(config)?;
    println!("built in {:.3} s", t.elapsed().as_secs_f64());
    let mut screen = facility.display();
    let (w, h) = screen.size();
    let bits = facility.config().screen.bits;
    screen.present(&vec![encode_grey(level, bits); w * h])?;
    let mut camera = facility.camera();
    let exposure = facility.config().camera.exposure;
    for _ in 0..3 {
        let t = Instant::now();
        let frame = camera.capture(&CaptureRequest {
            pattern: format!("level_{level}"),
            exposure_s: exposure,
            shutter: Default::default(),
        })?;
        let mean = frame.data.iter().map(|&v| v as f64).sum::<f64>() / frame.data.len() as f64;
        println!(
            "capture {}x{} in {:.3} s, mean {mean:.1} DN",
            frame.width,
            frame.height,
            t.elapsed().as_secs_f64()
        );
        if let Some(dir) = std::path::Path::new(out).parent() {
            std::fs::create_dir_all(dir)?;
        }
        write_png16(&frame, std::path::Path::new(out))?;
    }
    let reading = facility.meter().measure()?;
    println!(
        "meter {:.6} (true camera-effective radiance at the centre {:.6} W m-2 sr-1), virtual time {:.3} s",
        reading.value,
        facility.true_camera_effective_radiance(level as usize, (w as f64 / 2.0, h as f64 / 2.0)),
        facility.now()
    );
    Ok(())
}
