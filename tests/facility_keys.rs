//! Property tests of the facility file's `[acceptance]` keys and the
//! governor's `[timing]` keys: any value (any float including NaN and
//! infinities, any integer, strings, booleans) put into the bundled
//! facility file parses to `Ok` or to an error, never a panic; the error
//! is one line naming the key; and a value is accepted exactly when it is
//! in the range written here, independently of the parser's checks.

use optistim::facility::config::{FacilityConfig, GovernorMode};
use proptest::prelude::*;

fn bundled_text() -> String {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/configs/facility.toml");
    std::fs::read_to_string(path).unwrap()
}

/// A TOML value: its text and what it is.
#[derive(Clone, Debug)]
enum Value {
    Float(f64),
    Int(i64),
    Str(String),
    Bool(bool),
}

impl Value {
    fn toml(&self) -> String {
        match self {
            Value::Float(v) if v.is_nan() => "nan".into(),
            Value::Float(v) if v.is_infinite() => (if *v > 0.0 { "inf" } else { "-inf" }).into(),
            // Debug prints a float TOML reads back exactly ("0.1", "1e-7").
            Value::Float(v) => {
                let t = format!("{v:?}");
                if t.contains(['.', 'e']) {
                    t
                } else {
                    format!("{t}.0")
                }
            }
            Value::Int(v) => v.to_string(),
            Value::Str(s) => format!("{s:?}"),
            Value::Bool(b) => b.to_string(),
        }
    }
}

fn any_value() -> impl Strategy<Value = Value> {
    prop_oneof![
        any::<f64>().prop_map(Value::Float),
        (-2.0f64..12.0).prop_map(Value::Float),
        (-1e-3f64..1.1).prop_map(Value::Float),
        prop::sample::select(vec![0.0, 1.0, 1e-6, 9.9e-7, 10.0, 10.000001, -0.0])
            .prop_map(Value::Float),
        any::<i64>().prop_map(Value::Int),
        (-3i64..20).prop_map(Value::Int),
        "[a-z]{0,6}".prop_map(Value::Str),
        prop::sample::select(vec!["off", "auto", "fixed", "Auto", ""])
            .prop_map(|s| Value::Str(s.to_string())),
        any::<bool>().prop_map(Value::Bool),
    ]
}

/// The bundled file with `timing.key = value` (replacing its own).
fn with_timing(key: &str, value: &Value) -> String {
    let text: String = bundled_text()
        .lines()
        .filter(|l| !l.trim_start().starts_with(&format!("{key} ")))
        .map(|l| format!("{l}\n"))
        .collect();
    assert!(text.contains("[timing]\n"));
    text.replacen(
        "[timing]\n",
        &format!("[timing]\n{key} = {}\n", value.toml()),
        1,
    )
}

/// The bundled file with an `[acceptance]` table holding `key = value`.
fn with_acceptance(key: &str, value: &Value) -> String {
    let text = bundled_text();
    assert!(!text.contains("[acceptance]"));
    format!("{text}\n[acceptance]\n{key} = {}\n", value.toml())
}

/// A float key's value as the file gives it (an integer is read as a
/// float).
fn float(v: &Value) -> Option<f64> {
    match v {
        Value::Float(x) => Some(*x),
        Value::Int(x) => Some(*x as f64),
        _ => None,
    }
}

/// A non-negative integer key's value.
fn unsigned(v: &Value) -> Option<i64> {
    match v {
        Value::Int(x) if *x >= 0 => Some(*x),
        _ => None,
    }
}

fn fraction(v: &Value) -> bool {
    float(v).is_some_and(|x| x.is_finite() && (0.0..=1.0).contains(&x))
}

/// Whether `[acceptance] key = value` is valid, from the documented
/// ranges (defaults: missed_degraded 0.005 ≤ missed_fail 0.05).
fn acceptance_ok(key: &str, v: &Value) -> bool {
    match key {
        "max_sync_not_sent" => unsigned(v).is_some(),
        "allow_empty_frames" => matches!(v, Value::Bool(_)),
        "missed_degraded" => fraction(v) && float(v).unwrap() <= 0.05,
        "missed_fail" => fraction(v) && float(v).unwrap() >= 0.005,
        _ => fraction(v),
    }
}

/// Whether `timing.key = value` is valid, from the documented ranges.
fn timing_ok(key: &str, v: &Value) -> bool {
    match key {
        "governor" => matches!(v, Value::Str(s) if ["off", "auto", "fixed"].contains(&s.as_str())),
        "governor_rung" => unsigned(v).is_some_and(|x| x <= 16),
        "governor_max_block" => unsigned(v).is_some_and(|x| (1..=8).contains(&x)),
        "governor_max_pixel_error" => {
            float(v).is_some_and(|x| x.is_finite() && (1e-6..=10.0).contains(&x))
        }
        other => panic!("{other}"),
    }
}

/// Parses `text`: never a panic; an error is one line naming `key`; Ok
/// exactly when `ok`.
fn check(text: &str, key: &str, value: &Value, ok: bool) -> Result<(), TestCaseError> {
    let parsed = std::panic::catch_unwind(|| FacilityConfig::parse(text, "facility.toml"));
    let parsed = parsed.map_err(|_| TestCaseError::fail(format!("{key} = {value:?}: panicked")))?;
    match parsed {
        Ok(cfg) => {
            prop_assert!(ok, "{key} = {}: accepted", value.toml());
            if key == "governor" {
                let mode = match value {
                    Value::Str(s) if s == "auto" => GovernorMode::Auto,
                    Value::Str(s) if s == "fixed" => GovernorMode::Fixed,
                    _ => GovernorMode::Off,
                };
                prop_assert_eq!(cfg.timing.governor, mode);
            }
        }
        Err(e) => {
            let msg = e.to_string();
            prop_assert!(!ok, "{key} = {}: refused: {msg}", value.toml());
            prop_assert!(!msg.contains('\n'), "{key}: not one line: {msg}");
            prop_assert!(msg.contains(key), "{key} = {}: {msg}", value.toml());
            prop_assert!(msg.contains("facility.toml"), "{msg}");
        }
    }
    Ok(())
}

#[test]
fn the_bundled_file_parses() {
    FacilityConfig::parse(&bundled_text(), "facility.toml").unwrap();
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    #[test]
    fn acceptance_keys_are_range_checked(
        key in prop::sample::select(vec![
            "max_sync_not_sent",
            "max_safe_fraction",
            "missed_degraded",
            "missed_fail",
            "max_clip_flux",
            "allow_empty_frames",
        ]),
        value in any_value(),
    ) {
        let ok = acceptance_ok(key, &value);
        check(&with_acceptance(key, &value), key, &value, ok)?;
    }

    #[test]
    fn governor_keys_are_range_checked(
        key in prop::sample::select(vec![
            "governor",
            "governor_rung",
            "governor_max_block",
            "governor_max_pixel_error",
        ]),
        value in any_value(),
    ) {
        let ok = timing_ok(key, &value);
        check(&with_timing(key, &value), key, &value, ok)?;
    }
}
