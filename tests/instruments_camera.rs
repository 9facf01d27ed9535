//! The camera backends against real files and processes, and the frame
//! readers against files this test writes byte by byte (its own PNG, TIFF
//! and FITS writers, independent of the code under test): round trips,
//! malformed, truncated and huge inputs, random bytes.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use optistim::instruments::config::{open_camera, CameraConfig};
use optistim::instruments::frame::{
    read_frame, region_mean, saturated_pixels, subtract_dark, Rect,
};
use optistim::instruments::{CameraFrame, CaptureRequest};
use proptest::prelude::*;

// ---------- independent writers ----------

fn crc32(data: &[u8]) -> u32 {
    let mut c = 0xffff_ffffu32;
    for &b in data {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xedb8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

fn chunk(out: &mut Vec<u8>, kind: &[u8], data: &[u8]) {
    out.extend_from_slice(&(data.len() as u32).to_be_bytes());
    let mut body = kind.to_vec();
    body.extend_from_slice(data);
    out.extend_from_slice(&body);
    out.extend_from_slice(&crc32(&body).to_be_bytes());
}

/// A 16-bit grey PNG, zlib with stored (uncompressed) deflate blocks.
fn png16(w: u32, h: u32, px: &[u16]) -> Vec<u8> {
    let mut raw = Vec::new();
    for row in px.chunks(w as usize) {
        raw.push(0u8); // filter: none
        for v in row {
            raw.extend_from_slice(&v.to_be_bytes());
        }
    }
    let mut z = vec![0x78, 0x01];
    let blocks: Vec<&[u8]> = raw.chunks(65_535).collect();
    for (i, b) in blocks.iter().enumerate() {
        z.push((i + 1 == blocks.len()) as u8);
        z.extend_from_slice(&(b.len() as u16).to_le_bytes());
        z.extend_from_slice(&(!(b.len() as u16)).to_le_bytes());
        z.extend_from_slice(b);
    }
    let (mut a, mut b) = (1u32, 0u32);
    for &x in &raw {
        a = (a + x as u32) % 65_521;
        b = (b + a) % 65_521;
    }
    z.extend_from_slice(&((b << 16) | a).to_be_bytes());
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&w.to_be_bytes());
    ihdr.extend_from_slice(&h.to_be_bytes());
    ihdr.extend_from_slice(&[16, 0, 0, 0, 0]); // 16 bit, grey
    chunk(&mut out, b"IHDR", &ihdr);
    chunk(&mut out, b"IDAT", &z);
    chunk(&mut out, b"IEND", &[]);
    out
}

/// A little-endian baseline TIFF, one strip: `bits` 16 (uint) or 32 (float).
fn tiff(w: u32, h: u32, bits: u16, pixels: &[u8]) -> Vec<u8> {
    let entries: Vec<(u16, u16, u32)> = vec![
        (256, 4, w),
        (257, 4, h),
        (258, 3, bits as u32),
        (259, 3, 1),
        (262, 3, 1),
        (273, 4, 8),
        (277, 3, 1),
        (278, 4, h),
        (279, 4, pixels.len() as u32),
        (339, 3, if bits == 32 { 3 } else { 1 }),
    ];
    let mut out = b"II*\0".to_vec();
    let ifd = 8 + pixels.len() as u32;
    out.extend_from_slice(&ifd.to_le_bytes());
    out.extend_from_slice(pixels);
    out.extend_from_slice(&(entries.len() as u16).to_le_bytes());
    for (tag, ty, v) in entries {
        out.extend_from_slice(&tag.to_le_bytes());
        out.extend_from_slice(&ty.to_le_bytes());
        out.extend_from_slice(&1u32.to_le_bytes());
        if ty == 3 {
            out.extend_from_slice(&(v as u16).to_le_bytes());
            out.extend_from_slice(&[0, 0]);
        } else {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out.extend_from_slice(&0u32.to_le_bytes());
    out
}

fn card(text: &str) -> String {
    format!("{text:<80}")
}

/// A FITS primary HDU: the header cards given, END, padding, then `data`.
fn fits(cards: &[String], data: &[u8]) -> Vec<u8> {
    let mut h: String = cards.concat();
    h.push_str(&card("END"));
    while !h.len().is_multiple_of(2880) {
        h.push(' ');
    }
    let mut out = h.into_bytes();
    out.extend_from_slice(data);
    while !out.len().is_multiple_of(2880) {
        out.push(0);
    }
    out
}

fn fits_cards(bitpix: i32, w: usize, h: usize, extra: &[&str]) -> Vec<String> {
    let mut c = vec![
        card("SIMPLE  =                    T / conforms"),
        card(&format!("BITPIX  = {bitpix:>20}")),
        card("NAXIS   =                    2"),
        card(&format!("NAXIS1  = {w:>20}")),
        card(&format!("NAXIS2  = {h:>20}")),
    ];
    c.extend(extra.iter().map(|e| card(e)));
    c
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

// ---------- readers ----------

#[test]
fn png16_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (7u32, 5u32);
    let px: Vec<u16> = (0..w * h).map(|i| (i * 1873 % 65_536) as u16).collect();
    let (rw, rh, data) = read_frame(&write(dir.path(), "a.png", &png16(w, h, &px))).unwrap();
    assert_eq!((rw, rh), (7, 5));
    assert_eq!(data, px.iter().map(|&v| v as f32).collect::<Vec<_>>());
}

#[test]
fn tiff_16_bit_and_float_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (6u32, 4u32);
    let u: Vec<u16> = (0..w * h).map(|i| (65_535 - i * 999) as u16).collect();
    let bytes: Vec<u8> = u.iter().flat_map(|v| v.to_le_bytes()).collect();
    let (_, _, data) = read_frame(&write(dir.path(), "a.tif", &tiff(w, h, 16, &bytes))).unwrap();
    assert_eq!(data, u.iter().map(|&v| v as f32).collect::<Vec<_>>());
    let f: Vec<f32> = (0..w * h).map(|i| i as f32 * -0.37 + 1e4).collect();
    let bytes: Vec<u8> = f.iter().flat_map(|v| v.to_le_bytes()).collect();
    let (rw, rh, data) = read_frame(&write(dir.path(), "b.TIFF", &tiff(w, h, 32, &bytes))).unwrap();
    assert_eq!((rw, rh, data), (6, 4, f));
}

#[test]
fn fits_every_bitpix_with_bzero_bscale_and_row_order() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (3usize, 2usize);
    let vals = [0i64, 1, 2, 100, 120, 127];
    // 16-bit unsigned camera data as FITS stores it: i16 with BZERO 32768.
    let u16s = [0u32, 1, 40_000, 65_535, 32_768, 7];
    let bytes: Vec<u8> = u16s
        .iter()
        .flat_map(|&v| ((v as i32 - 32_768) as i16).to_be_bytes())
        .collect();
    let p = write(
        dir.path(),
        "u16.fits",
        &fits(
            &fits_cards(16, w, h, &["BZERO   =              32768.0"]),
            &bytes,
        ),
    );
    let (_, _, d) = read_frame(&p).unwrap();
    assert_eq!(d, u16s.iter().map(|&v| v as f32).collect::<Vec<_>>());
    type Enc = fn(i64) -> Vec<u8>;
    let cases: [(i32, Enc); 5] = [
        (8, |v| vec![v as u8]),
        (16, |v| (v as i16).to_be_bytes().to_vec()),
        (32, |v| (v as i32).to_be_bytes().to_vec()),
        (-32, |v| (v as f32).to_be_bytes().to_vec()),
        (-64, |v| (v as f64).to_be_bytes().to_vec()),
    ];
    for (bitpix, enc) in cases {
        let bytes: Vec<u8> = vals.iter().flat_map(|&v| enc(v)).collect();
        let extra = [
            "BSCALE  =                  0.5 / DN per count",
            "BZERO   =                 -1.0",
        ];
        let p = write(
            dir.path(),
            "x.fits",
            &fits(&fits_cards(bitpix, w, h, &extra), &bytes),
        );
        let (rw, rh, d) = read_frame(&p).unwrap();
        assert_eq!((rw, rh), (3, 2), "BITPIX {bitpix}");
        let want: Vec<f32> = vals.iter().map(|&v| v as f32 * 0.5 - 1.0).collect();
        assert_eq!(d, want, "BITPIX {bitpix}");
        // Bottom-up: the first stored row is the bottom one.
        let extra = ["ROWORDER= 'BOTTOM-UP'"];
        let p = write(
            dir.path(),
            "y.fit",
            &fits(&fits_cards(bitpix, w, h, &extra), &bytes),
        );
        let (_, _, d) = read_frame(&p).unwrap();
        let want: Vec<f32> = [100, 120, 127, 0, 1, 2].iter().map(|&v| v as f32).collect();
        assert_eq!(d, want, "BITPIX {bitpix} bottom-up");
    }
}

#[test]
fn malformed_frames_give_errors_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let one = [0u8; 8];
    let good = fits(&fits_cards(16, 2, 2, &[]), &one);
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("trunc.fits", good[..2880 + 4].to_vec(), "truncated"),
        ("hdr.fits", good[..1000].to_vec(), "truncated"),
        (
            "naxis.fits",
            fits(
                &fits_cards(16, 2, 2, &[])
                    .into_iter()
                    .map(|c| {
                        c.replace(
                            "NAXIS   =                    2",
                            "NAXIS   =                    3",
                        )
                    })
                    .collect::<Vec<_>>(),
                &one,
            ),
            "NAXIS",
        ),
        (
            "bitpix.fits",
            fits(&fits_cards(24, 2, 2, &[]), &one),
            "BITPIX",
        ),
        (
            "huge.fits",
            fits(&fits_cards(16, 100_000, 100_000, &[]), &one),
            "at most",
        ),
        (
            "neg.fits",
            fits(&fits_cards(16, 2, 0, &[]), &one),
            "non-empty",
        ),
        (
            "noend.fits",
            vec![b' '; 2880 * 70]
                .iter()
                .enumerate()
                .map(|(i, &b)| {
                    if i < 80 {
                        card("SIMPLE  =                    T").as_bytes()[i]
                    } else {
                        b
                    }
                })
                .collect(),
            "END",
        ),
        (
            "notfits.fits",
            fits(&[card("SIMPLE  =                    F")], &one),
            "SIMPLE",
        ),
        (
            "nan.fits",
            fits(&fits_cards(-32, 1, 1, &[]), &f32::NAN.to_be_bytes()),
            "not finite",
        ),
        (
            "bzero.fits",
            fits(&fits_cards(16, 2, 2, &["BZERO   = 'abc'"]), &one),
            "BZERO",
        ),
        ("trunc.png", png16(4, 4, &[7; 16])[..40].to_vec(), "PNG"),
        ("huge.png", png16(1 << 14, 1 << 13, &[]), "at most"),
        ("trunc.tif", tiff(4, 4, 16, &[0; 32])[..20].to_vec(), "TIFF"),
        ("huge.tif", tiff(1 << 14, 1 << 13, 16, &[0; 32]), "at most"),
        ("rgb.bmp", vec![0; 10], "unknown frame format"),
    ];
    for (name, bytes, want) in cases {
        let p = write(d, name, &bytes);
        let e = read_frame(&p).unwrap_err().to_string();
        assert!(e.contains(name) && e.contains(want), "{name}: {e}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn random_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..6000), ext in 0usize..3) {
        let dir = tempfile::tempdir().unwrap();
        let name = ["r.fits", "r.png", "r.tif"][ext];
        // Random bytes after a valid FITS start reach the header parser.
        let mut b = if ext == 0 { card("SIMPLE  =                    T").into_bytes() } else { Vec::new() };
        b.extend_from_slice(&bytes);
        let p = write(dir.path(), name, &b);
        if let Err(e) = read_frame(&p) {
            prop_assert!(e.to_string().contains(name));
        }
    }

    #[test]
    fn fits_header_mutations_never_panic(pos in 0usize..480, byte in 0x20u8..0x7f, bitpix in prop::sample::select(vec![8, 16, 32, -32, -64])) {
        let dir = tempfile::tempdir().unwrap();
        let mut b = fits(&fits_cards(bitpix, 4, 3, &["BZERO   =                  1.0"]), &[1u8; 96]);
        b[pos] = byte;
        let p = write(dir.path(), "m.fits", &b);
        match read_frame(&p) {
            Ok((w, h, d)) => prop_assert_eq!(w * h, d.len()),
            Err(e) => prop_assert!(e.to_string().contains("m.fits")),
        }
    }
}

// ---------- frame helpers ----------

fn frame(w: usize, h: usize, data: Vec<f32>, sat: f32) -> CameraFrame {
    CameraFrame {
        width: w,
        height: h,
        data,
        exposure_s: 0.01,
        saturation_dn: sat,
    }
}

#[test]
fn region_statistics_dark_and_saturation() {
    let data: Vec<f32> = (0..20).map(|i| i as f32).collect();
    let f = frame(5, 4, data, 1000.0);
    let dark = frame(5, 4, vec![2.0; 20], 1000.0);
    // Rows 1..3, columns 1..4: values 6,7,8,11,12,13 minus 2.
    let r = Rect {
        x: 1,
        y: 1,
        width: 3,
        height: 2,
    };
    let s = region_mean(&f, Some(&dark), r, "p").unwrap();
    let vals = [4.0, 5.0, 6.0, 9.0, 10.0, 11.0];
    let mean = vals.iter().sum::<f64>() / 6.0;
    let var = vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / 5.0;
    assert!(
        (s.mean - mean).abs() < 1e-12 && (s.std - var.sqrt()).abs() < 1e-12,
        "{s:?}"
    );
    assert_eq!(s.pixels, 6);
    assert_eq!(subtract_dark(&f, &dark).unwrap()[19], 17.0);
    let mut other = dark.clone();
    other.exposure_s = 0.02;
    assert!(subtract_dark(&f, &other)
        .unwrap_err()
        .to_string()
        .contains("exposure"));
    assert_eq!(
        Rect::centred(5, 4, 0.5),
        Rect {
            x: 1,
            y: 1,
            width: 3,
            height: 2
        }
    );

    let sat = frame(5, 4, (0..20).map(|i| i as f32).collect(), 12.0);
    assert_eq!(saturated_pixels(&sat), 8);
    let e = region_mean(&sat, None, r, "level_0255_r1")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("level_0255_r1") && e.contains("2 pixels") && e.contains("saturated"),
        "{e}"
    );
    let e = region_mean(
        &f,
        None,
        Rect {
            x: 4,
            y: 0,
            width: 2,
            height: 1,
        },
        "p",
    )
    .unwrap_err();
    assert!(e.to_string().contains("not inside"), "{e}");
}

// ---------- backends ----------

fn camera_cfg(kind: &str, dir: &Path, extra: &str) -> CameraConfig {
    let text = format!(
        "kind = \"{kind}\"\nname = \"navcam\"\ndir = \"{}\"\npattern = \"cal_{{pattern}}\"\n\
         timeout = 1.0\npoll = 0.02\nexposure = 0.01\nsaturation_dn = 60000\n{extra}\n",
        dir.display()
    );
    toml::from_str(&text).unwrap()
}

fn req(p: &str) -> CaptureRequest {
    CaptureRequest {
        pattern: p.into(),
        exposure_s: 0.0125,
        shutter: Default::default(),
    }
}

#[test]
fn files_camera_waits_for_a_frame_written_later() {
    let dir = tempfile::tempdir().unwrap();
    let mut cam = open_camera(
        &camera_cfg("files", dir.path(), "resolution = [4, 3]"),
        dir.path(),
    )
    .unwrap();
    let px: Vec<u16> = (0..12).map(|i| i * 100).collect();
    let bytes = png16(4, 3, &px);
    let target = dir.path().join("cal_level_0001.png");
    let writer = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(200));
        // Written in two parts: a half-written file must not be read.
        let mut f = std::fs::File::create(&target).unwrap();
        f.write_all(&bytes[..30]).unwrap();
        f.flush().unwrap();
        std::thread::sleep(Duration::from_millis(100));
        f.write_all(&bytes[30..]).unwrap();
    });
    let t0 = Instant::now();
    let f = cam.capture(&req("level_0001")).unwrap();
    writer.join().unwrap();
    assert!(t0.elapsed() >= Duration::from_millis(300));
    assert_eq!(
        (f.width, f.height, f.exposure_s, f.saturation_dn),
        (4, 3, 0.0125, 60000.0)
    );
    assert_eq!(f.data, px.iter().map(|&v| v as f32).collect::<Vec<_>>());

    // Never written: a timeout naming the pattern.
    let t0 = Instant::now();
    let e = cam.capture(&req("level_0002")).unwrap_err().to_string();
    assert!(
        e.contains("navcam") && e.contains("level_0002") && e.contains("within 1 s"),
        "{e}"
    );
    assert!(t0.elapsed() < Duration::from_secs(2));

    // Wrong size.
    write(dir.path(), "cal_level_0003.png", &png16(5, 3, &[1; 15]));
    let e = cam.capture(&req("level_0003")).unwrap_err().to_string();
    assert!(
        e.contains("level_0003") && e.contains("5 × 3") && e.contains("4 × 3"),
        "{e}"
    );

    // Saturated: the frame arrives; the region statistics name the pattern.
    write(
        dir.path(),
        "cal_level_0255.png",
        &png16(4, 3, &[65_535; 12]),
    );
    let f = cam.capture(&req("level_0255")).unwrap();
    assert_eq!(saturated_pixels(&f), 12);
    let e = region_mean(&f, None, Rect::centred(4, 3, 1.0), "level_0255").unwrap_err();
    assert!(
        e.to_string().contains("level_0255") && e.to_string().contains("12 pixels"),
        "{e}"
    );

    // A pattern name that is not a file name.
    assert!(cam.capture(&req("../etc")).is_err());
}

#[cfg(unix)]
#[test]
fn command_camera_runs_a_real_command() {
    let dir = tempfile::tempdir().unwrap();
    let frame_bytes = png16(2, 2, &[10, 20, 30, 40]);
    let src = write(dir.path(), "source.png", &frame_bytes);
    // The "camera": copies a frame to {path}, logs its arguments.
    let script = write(
        dir.path(),
        "grab.sh",
        format!(
            "#!/bin/sh\necho \"$@\" > '{}/args.txt'\ncp '{}' \"$3\"\n",
            dir.path().display(),
            src.display()
        )
        .as_bytes(),
    );
    let cmd = format!(
        "command = \"sh {} --exposure {{exposure_us}} {{path}} {{pattern}}\"",
        script.display()
    );
    let mut cam = open_camera(&camera_cfg("command", dir.path(), &cmd), dir.path()).unwrap();
    let f = cam.capture(&req("flat_0128")).unwrap();
    assert_eq!(f.data, vec![10.0, 20.0, 30.0, 40.0]);
    let out = dir.path().join("cal_flat_0128.png");
    let args = std::fs::read_to_string(dir.path().join("args.txt")).unwrap();
    assert_eq!(
        args.trim(),
        format!("--exposure 12500 {} flat_0128", out.display())
    );

    // Exit 3 with a message: the error quotes stderr's last line.
    let fail = write(
        dir.path(),
        "fail.sh",
        b"#!/bin/sh\necho starting >&2\necho 'camera not found on bus 2' >&2\nexit 3\n",
    );
    let cmd = format!("command = \"sh {} {{path}}\"", fail.display());
    let mut cam = open_camera(&camera_cfg("command", dir.path(), &cmd), dir.path()).unwrap();
    let e = cam.capture(&req("dots_01")).unwrap_err().to_string();
    assert!(
        e.contains("dots_01") && e.contains("camera not found on bus 2") && e.contains('3'),
        "{e}"
    );
    assert!(!e.contains("starting"), "{e}");

    // A command leaving a background process that holds stderr open.
    let bg = write(
        dir.path(),
        "bg.sh",
        format!("#!/bin/sh\ncp '{}' \"$1\"\nsleep 20 &\n", src.display()).as_bytes(),
    );
    let cmd = format!("command = \"sh {} {{path}}\"", bg.display());
    let mut cam = open_camera(&camera_cfg("command", dir.path(), &cmd), dir.path()).unwrap();
    let t0 = Instant::now();
    assert_eq!(cam.capture(&req("bg")).unwrap().data.len(), 4);
    assert!(t0.elapsed() < Duration::from_secs(3), "{:?}", t0.elapsed());

    // Exit 0 without writing the file; a command that hangs is killed.
    let cmd = "command = \"true {path}\"";
    let mut cam = open_camera(&camera_cfg("command", dir.path(), cmd), dir.path()).unwrap();
    let e = cam.capture(&req("dots_02")).unwrap_err().to_string();
    assert!(e.contains("wrote no"), "{e}");
    let cmd = "command = \"sleep 30 {pattern}\"";
    let mut cam = open_camera(&camera_cfg("command", dir.path(), cmd), dir.path()).unwrap();
    let t0 = Instant::now();
    let e = cam.capture(&req("7")).unwrap_err().to_string();
    assert!(
        e.contains("killed") && t0.elapsed() < Duration::from_secs(3),
        "{e}"
    );
    let cmd = "command = \"/nonexistent/grab {path}\"";
    let mut cam = open_camera(&camera_cfg("command", dir.path(), cmd), dir.path()).unwrap();
    let e = cam.capture(&req("x")).unwrap_err().to_string();
    assert!(
        e.contains("cannot run") && e.contains("/nonexistent/grab"),
        "{e}"
    );
}

#[test]
fn sim_kind_and_missing_dir_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let e = open_camera(&camera_cfg("sim", dir.path(), ""), dir.path())
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("calibrate.camera.kind") && e.contains("simulated"),
        "{e}"
    );
    let e = open_camera(
        &camera_cfg("files", &dir.path().join("nope"), ""),
        dir.path(),
    )
    .err()
    .unwrap()
    .to_string();
    assert!(
        e.contains("calibrate.camera.dir") && e.contains("nope"),
        "{e}"
    );
}

// ---------- intrinsics ----------

mod intrinsics {
    use glam::DVec3;
    use optistim::instruments::intrinsics::CameraIntrinsics;
    use std::path::Path;

    const FILE: &str = "width = 1024\nheight = 768\n\
        camera_matrix = [[2400.0, 0.0, 511.5], [0.0, 2410.0, 383.5], [0.0, 0.0, 1.0]]\n\
        distortion = [-0.12, 0.03, 1e-4, -2e-4, 0.01]\n";

    #[test]
    fn brown_conrady_forward_and_inverse() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("k.toml");
        std::fs::write(&p, FILE).unwrap();
        let k = CameraIntrinsics::load(&p).unwrap();
        // The boresight lands on OpenCV's (cx, cy), i.e. this crate's +0.5.
        let (u, v) = k.direction_to_pixel(DVec3::Z).unwrap();
        assert_eq!((u, v), (512.0, 384.0));
        for &(x, y) in &[(0.1, -0.05), (-0.2, 0.15), (0.0, 0.18), (0.21, 0.16)] {
            // OpenCV's model written out here, independently.
            let (k1, k2, p1, p2, k3) = (-0.12, 0.03, 1e-4, -2e-4, 0.01);
            let r2: f64 = x * x + y * y;
            let rad = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
            let xd = x * rad + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
            let yd = y * rad + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
            let want = (2400.0 * xd + 511.5 + 0.5, 2410.0 * yd + 383.5 + 0.5);
            let got = k.direction_to_pixel(DVec3::new(x, y, 1.0) * 3.0).unwrap();
            assert!((got.0 - want.0).abs() < 1e-9 && (got.1 - want.1).abs() < 1e-9);
            let d = k.pixel_to_direction(want.0, want.1).unwrap();
            let truth = DVec3::new(x, y, 1.0).normalize();
            assert!((d - truth).length() < 1e-11, "{x} {y}: {d}");
        }
        assert!(k.direction_to_pixel(-DVec3::Z).is_none());
        let j = "{\"width\": 1024, \"height\": 768, \"camera_matrix\": [[2400.0, 0.0, 511.5], [0.0, 2410.0, 383.5], [0.0, 0.0, 1.0]], \"distortion\": [-0.12, 0.03, 1e-4, -2e-4, 0.01]}";
        assert_eq!(
            CameraIntrinsics::parse(j, true, Path::new("k.json")).unwrap(),
            k
        );
    }

    #[test]
    fn bad_intrinsics_name_file_and_key() {
        let cases = [
            ("2400.0, 0.0, 511.5", "-1.0, 0.0, 511.5", "camera_matrix"),
            ("2400.0, 0.0, 511.5", "2400.0, 0.5, 511.5", "skew"),
            ("-0.12,", "nan,", "distortion"),
            ("width = 1024", "width = 0", "width"),
            ("0.01]", "0.01, 0.0]", "distortion"),
            ("height = 768", "height = 768\nfov = 3", "fov"),
            (
                "[0.0, 0.0, 1.0]]",
                "[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]",
                "camera_matrix",
            ),
            ("[0.0, 0.0, 1.0]]", "[0.0, 0.0]]", "camera_matrix"),
        ];
        for (from, to, key) in cases {
            let text = FILE.replacen(from, to, 1);
            assert_ne!(text, FILE);
            let e = CameraIntrinsics::parse(&text, false, Path::new("cam/k.toml"))
                .map(|_| format!("{to}: accepted"))
                .unwrap_or_else(|e| e.to_string());
            assert!(e.contains("cam/k.toml") && e.contains(key), "{key}: {e}");
        }
    }
}
