//! PDS3 label parser and AMIE image reader, on the real SMART-1 files and on
//! small hand-written labels (syntax corners, truncated and foreign files).

mod common;
use common::{IMG1, IMG2};
use optistim::validate::pds3::{read_image, Label, Value};

#[test]
fn parses_the_amie_label() {
    let label = Label::read(IMG1).unwrap();
    let r = &label.root;
    assert_eq!(r.string("PDS_VERSION_ID").unwrap(), "PDS3");
    assert_eq!(
        r.string("FILE_NAME").unwrap(),
        "AMI_EE3_040819_00208_00030.IMG"
    );
    assert_eq!(r.i64("RECORD_BYTES").unwrap(), 1024);
    assert_eq!(r.i64("LABEL_RECORDS").unwrap(), 20);
    // Multi-line quoted string, collapsed.
    assert_eq!(
        r.string("DATA_SET_NAME").unwrap(),
        "SMART-1 LUNAR/OTHER AMIE 2 EDR RAW DATA EARTH ESCAPE PHASE V1.1"
    );
    // Units.
    assert_eq!(
        r.f64_with_unit("EXPOSURE_DURATION").unwrap(),
        (30.0, Some("MS".into()))
    );
    assert_eq!(r.f64_in("TARGET_CENTER_DISTANCE", "KM").unwrap(), 197936.0);
    assert!(r.f64_in("TARGET_CENTER_DISTANCE", "M").is_err());
    assert_eq!(r.f64_in("PHASE_ANGLE", "DEG").unwrap(), 105.18);
    // No unit given: accepted by f64_in.
    assert_eq!(r.f64_in("WESTERNMOST_LONGITUDE", "DEG").unwrap(), 293.46);
    // Sequences, including the namespaced SMART-1 keys.
    let v: [f64; 3] = r.f64_array("SC_TARGET_POSITION_VECTOR").unwrap();
    assert_eq!(v, [-146915.0, -122553.1, -50748.3]);
    let (ra, _) = r.f64_seq("RETICLE_POINT_RA").unwrap();
    assert_eq!(ra, vec![220.60, 221.43, 218.83, 217.98]);
    let att: [f64; 3] = r.f64_array("SMART1:AMIE_SC_ATTITUDE_VECTOR").unwrap();
    assert_eq!(att, [230.04, 340.11, 77.23]);
    // Objects.
    let img = r.object("IMAGE").unwrap();
    assert_eq!(img.i64("LINES").unwrap(), 512);
    assert_eq!(img.string("SAMPLE_TYPE").unwrap(), "LSB_UNSIGNED_INTEGER");
    assert_eq!(img.f64("SCALING_FACTOR").unwrap(), 0.015625);
    assert_eq!(
        r.object("BROWSE_IMAGE")
            .unwrap()
            .i64("SAMPLE_BITS")
            .unwrap(),
        8
    );
    // Pointers: 1-based bytes -> 0-based offset.
    assert_eq!(label.pointer("IMAGE").unwrap(), 36864);
    assert_eq!(label.pointer("BROWSE_IMAGE").unwrap(), 20480);
    // The label ends inside the 20 label records.
    assert!(label.label_len <= 20 * 1024);
}

#[test]
fn missing_and_mistyped_keys_name_file_and_key() {
    let label = Label::read(IMG1).unwrap();
    let e = label.root.f64("NO_SUCH_KEY").unwrap_err().to_string();
    assert!(
        e.contains("AMI_EE3_040819_00208_00030.IMG") && e.contains("NO_SUCH_KEY"),
        "{e}"
    );
    let e = label
        .root
        .f64("RETICLE_POINT_LATITUDE")
        .unwrap_err()
        .to_string(); // "N/A"
    assert!(
        e.contains("RETICLE_POINT_LATITUDE")
            && e.contains("expected a number")
            && e.contains("N/A"),
        "{e}"
    );
    let e = label
        .root
        .object("IMAGE")
        .unwrap()
        .f64("NOPE")
        .unwrap_err()
        .to_string();
    assert!(e.contains("OBJECT IMAGE") && e.contains("NOPE"), "{e}");
}

#[test]
fn reads_the_amie_image() {
    for path in [IMG1, IMG2] {
        let img = read_image(path).unwrap();
        assert_eq!((img.scaled.width, img.scaled.height), (512, 512));
        // 10-bit data in the top bits of a u16: DN = raw / 64, exact.
        assert!(img.raw.iter().all(|&v| v % 64 == 0));
        for (r, d) in img.raw.iter().zip(&img.scaled.data) {
            assert_eq!(*d, (*r / 64) as f32);
        }
        let (lo, hi) = img.scaled.min_max().unwrap();
        assert!(lo >= 0.0 && hi <= 1023.0);
        // First pixel straight from the bytes.
        let bytes = std::fs::read(path).unwrap();
        assert_eq!(img.raw[0], u16::from_le_bytes([bytes[36864], bytes[36865]]));
        let last = 36864 + 2 * (512 * 512 - 1);
        assert_eq!(
            img.raw[512 * 512 - 1],
            u16::from_le_bytes([bytes[last], bytes[last + 1]])
        );
    }
    // Image 1: the sky is ~30-50 DN and the lit crescent reaches >700 DN.
    let img = read_image(IMG1).unwrap();
    let mut v = img.scaled.data.clone();
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    assert!(
        (30.0..50.0).contains(&v[v.len() / 2]),
        "median {}",
        v[v.len() / 2]
    );
    assert!(v[v.len() * 999 / 1000] > 700.0);
}

#[test]
fn truncated_file_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = std::fs::read(IMG1).unwrap();
    // Cut inside the image: record count no longer matches.
    let p = dir.path().join("cut.IMG");
    std::fs::write(&p, &bytes[..bytes.len() - 1000]).unwrap();
    let e = read_image(&p).unwrap_err().to_string();
    assert!(e.contains("cut.IMG") && e.contains("FILE_RECORDS"), "{e}");
    // Cut inside the label.
    let p = dir.path().join("label_cut.IMG");
    std::fs::write(&p, &bytes[..3000]).unwrap();
    let e = Label::read(&p).unwrap_err().to_string();
    assert!(e.contains("label_cut.IMG"), "{e}");
    // Cut in the middle of a multi-line quoted string.
    let text = String::from_utf8_lossy(&bytes[..20480]).into_owned();
    let at = text.find("SMALL MISSIONS").unwrap();
    let p = dir.path().join("quote_cut.lbl");
    std::fs::write(&p, &text[..at]).unwrap();
    let e = Label::read(&p).unwrap_err().to_string();
    assert!(
        e.contains("quote_cut.lbl") && e.contains("unterminated quoted string"),
        "{e}"
    );
}

#[test]
fn foreign_files_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("image.png");
    std::fs::write(&p, b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR").unwrap();
    let e = Label::read(&p).unwrap_err().to_string();
    assert!(
        e.contains("image.png") && e.contains("not a PDS3 file"),
        "{e}"
    );
    let p = dir.path().join("other.lbl");
    std::fs::write(&p, "PDS_VERSION_ID = PDS4\nEND\n").unwrap();
    assert!(Label::read(&p)
        .unwrap_err()
        .to_string()
        .contains("not a PDS3 file"));
    let p = dir.path().join("odl.lbl");
    std::fs::write(&p, "ODL_VERSION_ID = ODL3\nEND\n").unwrap();
    assert!(Label::read(&p)
        .unwrap_err()
        .to_string()
        .contains("not a PDS3 file"));
    // A label without an IMAGE object cannot be read as an image.
    let p = dir.path().join("noimage.lbl");
    std::fs::write(
        &p,
        "PDS_VERSION_ID = PDS3\r\nRECORD_TYPE = STREAM\r\nEND\r\n",
    )
    .unwrap();
    let e = read_image(&p).unwrap_err().to_string();
    assert!(e.contains("noimage.lbl") && e.contains("IMAGE"), "{e}");
}

#[test]
fn syntax_corners() {
    let text = br#"PDS_VERSION_ID = PDS3 /* trailing comment */
/* a comment
   over two lines */
A = 1.5 <KM>
B = "multi
     line"
C = (1, 2.5, -3e2) <DEG>
D = {RED, GREEN}
E = ((1, 2), (3, 4))
F = 'SYMBOL'
^G = 3
RECORD_BYTES = 100
H = 16#FF#
I = 2004-08-19T23:42:43.134
GROUP = OUTER
  OBJECT = INNER
    X = 7
  END_OBJECT = INNER
END_GROUP
END
binary \x00\x01 follows"#;
    let label = Label::parse(text, "mem.lbl").unwrap();
    let r = &label.root;
    assert_eq!(r.f64_with_unit("A").unwrap(), (1.5, Some("KM".into())));
    assert_eq!(r.string("B").unwrap(), "multi line");
    assert_eq!(
        r.f64_seq("C").unwrap(),
        (vec![1.0, 2.5, -300.0], Some("DEG".into()))
    );
    assert!(matches!(r.get("D").unwrap(), Value::Sequence { items, .. } if items.len() == 2));
    assert!(matches!(r.get("E").unwrap(), Value::Sequence { items, .. } if items.len() == 2));
    assert!(r.f64_seq("E").is_err());
    assert_eq!(r.string("F").unwrap(), "SYMBOL");
    assert_eq!(label.pointer("G").unwrap(), 200); // records, 1-based
    assert_eq!(r.f64("H").unwrap(), 255.0);
    assert_eq!(r.string("I").unwrap(), "2004-08-19T23:42:43.134");
    assert_eq!(
        r.object("OUTER")
            .unwrap()
            .object("INNER")
            .unwrap()
            .i64("X")
            .unwrap(),
        7
    );
    // Unbalanced objects.
    let e = Label::parse(b"PDS_VERSION_ID = PDS3\nOBJECT = A\nEND\n", "x.lbl")
        .unwrap_err()
        .to_string();
    assert!(e.contains("END_OBJECT"), "{e}");
    let e = Label::parse(
        b"PDS_VERSION_ID = PDS3\nOBJECT = A\nEND_OBJECT = B\nEND\n",
        "x.lbl",
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("closes OBJECT `A`"), "{e}");
    // No END at all.
    let e = Label::parse(b"PDS_VERSION_ID = PDS3\nA = 1\n", "x.lbl")
        .unwrap_err()
        .to_string();
    assert!(e.contains("truncated"), "{e}");
}

/// The real file with one label value replaced in place (same length, so
/// the record count still matches).
fn patched(dir: &std::path::Path, from: &str, to: &str) -> std::path::PathBuf {
    let mut bytes = std::fs::read(IMG1).unwrap();
    let at = bytes
        .windows(from.len())
        .position(|w| w == from.as_bytes())
        .unwrap_or_else(|| panic!("`{from}` not in the label"));
    // The label's lines are padded with spaces: those are room too.
    let mut end = at + from.len();
    while bytes[end] == b' ' {
        end += 1;
    }
    assert!(to.len() <= end - at, "{to}");
    let padded = format!("{to:<width$}", width = end - at);
    bytes[at..end].copy_from_slice(padded.as_bytes());
    let p = dir.join("patched.IMG");
    std::fs::write(&p, bytes).unwrap();
    p
}

/// Sizes and offsets near 2^62–2^64 from the label give an error naming the
/// keyword, never a wrapped slice bound, a capacity overflow or a panic.
#[test]
fn hostile_sizes_name_the_keyword() {
    let dir = tempfile::tempdir().unwrap();
    let lines = "LINES                       = 512";
    let cases = [
        (lines, "LINES = 4611686018427387904", "LINES"),
        (lines, "LINES = 9223372036854775807", "LINES"),
        (
            "LINE_SAMPLES                = 512",
            "LINE_SAMPLES = 9223372036854775807",
            "LINES",
        ),
        (
            "^IMAGE                         = 36865 <BYTES>",
            "^IMAGE = 18446744073709551615 <BYTES>",
            "IMAGE",
        ),
        (
            "^IMAGE                         = 36865 <BYTES>",
            "^IMAGE = 18014398509481984",
            "^IMAGE",
        ),
        (
            "LABEL_RECORDS                  = 20",
            "LABEL_RECORDS = 9223372036854775807",
            "LABEL_RECORDS",
        ),
        (
            "SCALING_FACTOR              = 0.015625",
            "SCALING_FACTOR = 1e999",
            "SCALING_FACTOR",
        ),
    ];
    for (from, to, key) in cases {
        let p = patched(dir.path(), from, to);
        let e = read_image(&p).unwrap_err().to_string();
        assert!(e.contains("patched.IMG") && e.contains(key), "{to}: {e}");
    }
    // The prefix of the second image object (the first LINE_PREFIX_BYTES is
    // the browse image's, which read_image does not read).
    let mut bytes = std::fs::read(IMG1).unwrap();
    let text = String::from_utf8_lossy(&bytes[..20480]).into_owned();
    let image_obj = text.find("OBJECT                         = IMAGE").unwrap();
    let from = "LINE_PREFIX_BYTES           = 0";
    if let Some(rel) = text[image_obj..].find(from) {
        let at = image_obj + rel;
        let to = format!("{:<w$}", "LINE_PREFIX_BYTES = -9", w = from.len());
        bytes[at..at + from.len()].copy_from_slice(to.as_bytes());
        let p = dir.path().join("prefix.IMG");
        std::fs::write(&p, bytes).unwrap();
        let e = read_image(&p).unwrap_err().to_string();
        assert!(e.contains("LINE_PREFIX_BYTES"), "{e}");
    }
}

/// Tens of thousands of nested parentheses: an error, not a stack overflow.
#[test]
fn deep_nesting_is_refused() {
    for depth in [33, 50_000] {
        let mut text = String::from("PDS_VERSION_ID = PDS3\nA = ");
        text.push_str(&"(".repeat(depth));
        text.push('1');
        text.push_str(&")".repeat(depth));
        text.push_str("\nEND\n");
        let e = Label::parse(text.as_bytes(), "deep.lbl")
            .unwrap_err()
            .to_string();
        assert!(e.contains("deep.lbl") && e.contains("nested"), "{e}");
    }
    let ok = "PDS_VERSION_ID = PDS3\nA = ".to_string()
        + &"(".repeat(8)
        + "1"
        + &")".repeat(8)
        + "\nEND\n";
    Label::parse(ok.as_bytes(), "ok.lbl").unwrap();
}
