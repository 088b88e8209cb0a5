//! A system's identity by its prescription: the SHA-256 of its canonical JSON ([`system_sha256`], the
//! fingerprint a learned reconstruction records of the system it was trained for; Python's
//! `diffcassi.unrolled.system_sha256` calls the same function), and the first place two prescriptions differ
//! ([`first_difference`], to say *what* differs when two fingerprints do not match).
//!
//! **What is compared** ([`prescription`]): the spec's JSON value with two changes, so that the identity is
//! what the designer specified and the same on every machine.
//! 1. A *derived* cell — one that holds a `solve` or a `pickup` — keeps its rule and drops its value: the
//!    value follows from the rest of the spec when the system is built. A solved value is the output of an
//!    iteration through `sin`, `asin`, `atan2` … of the platform's libm, whose last bit may differ between
//!    glibc versions and CPUs; with the value in the hash, weights trained on a GPU machine could be refused
//!    on the machine that built them. A spec file and the system built from it hash the same.
//! 2. Every other float is rounded to 12 significant digits (−0 written as 0): values a program computed
//!    rather than a designer typed (the dual-disperser presets copy SP's solved values) are then equal across
//!    machines too, while any change a tolerance could see (1e-12 relative: 2e-12 mm on 2 mm) still shows.
//!
//! ```
//! use diffcassi::spec::{first_difference, system_sha256};
//! let sp = diffcassi::presets::spec("sp")?;
//! let mut moved = sp.clone();
//! moved.surfaces[2].thickness_mm.value += 0.5;
//! assert_ne!(system_sha256(&sp)?, system_sha256(&moved)?);
//! assert!(first_difference(&sp, &moved).unwrap().starts_with("surfaces[2].thickness_mm"));
//! assert_eq!(first_difference(&sp, &sp.clone()), None);
//! // The built system (its chief-ray solves done) is the same prescription.
//! let built = diffcassi::system::SequentialSystem::build(&sp)?.spec;
//! assert_eq!(system_sha256(&built)?, system_sha256(&sp)?);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::SystemSpec;
use crate::error::{Error, Result};
use serde_json::Value;

/// Significant digits a float of the prescription keeps ([`prescription`]).
pub const PRESCRIPTION_DIGITS: usize = 12;

/// SHA-256 (hex) of the spec's canonical prescription ([`prescription`], written as compact JSON): equal for
/// equal prescriptions (name included) on every platform, whether the spec is a file's or a built system's.
pub fn system_sha256(spec: &SystemSpec) -> Result<String> {
    let text = serde_json::to_string(&prescription(spec)?).map_err(|e| Error::invalid(format!("cannot write spec `{}` as JSON: {e}", spec.name)))?;
    Ok(crate::io::sha256::sha256_hex(text.as_bytes()))
}

/// The spec's prescription as compared (module docs): its JSON value with derived cells' values left out
/// and every other float rounded to [`PRESCRIPTION_DIGITS`] significant digits.
pub fn prescription(spec: &SystemSpec) -> Result<Value> {
    let mut v = serde_json::to_value(spec).map_err(|e| Error::invalid(format!("cannot write spec `{}` as JSON: {e}", spec.name)))?;
    canonical(&mut v);
    Ok(v)
}

fn canonical(v: &mut Value) {
    match v {
        Value::Object(map) => {
            if map.contains_key("solve") || map.contains_key("pickup") {
                map.remove("value");
            }
            map.values_mut().for_each(canonical);
        }
        Value::Array(items) => items.iter_mut().for_each(canonical),
        Value::Number(n) if n.is_f64() => {
            let x = n.as_f64().unwrap_or(0.0);
            // Rust's float formatting and parsing are exact (no libm): the nearest double to the rounded decimal.
            let r: f64 = format!("{:.*e}", PRESCRIPTION_DIGITS - 1, x).parse().unwrap_or(x);
            *v = serde_json::Number::from_f64(if r == 0.0 { 0.0 } else { r }).map_or(Value::Null, Value::Number);
        }
        _ => {}
    }
}

/// The first field, in the spec's JSON order, where the prescriptions of `a` and `b` differ
/// ([`prescription`]: derived values left out, floats to 12 significant digits), as `path: A ≠ B`
/// (`surfaces[2].thickness_mm.value: 10.0 ≠ 10.5`); `None` when they are the same prescription (equal
/// [`system_sha256`]).
pub fn first_difference(a: &SystemSpec, b: &SystemSpec) -> Option<String> {
    let (a, b) = (prescription(a).ok()?, prescription(b).ok()?);
    differ(&a, &b, String::new())
}

fn differ(a: &Value, b: &Value, path: String) -> Option<String> {
    let at = |key: &str| if path.is_empty() { key.to_string() } else { format!("{path}.{key}") };
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            for (k, v) in x {
                match y.get(k) {
                    Some(w) => {
                        if let Some(d) = differ(v, w, at(k)) {
                            return Some(d);
                        }
                    }
                    None => return Some(format!("{}: {} ≠ (absent)", at(k), short(v))),
                }
            }
            y.iter().find(|(k, _)| !x.contains_key(*k)).map(|(k, w)| format!("{}: (absent) ≠ {}", at(k), short(w)))
        }
        (Value::Array(x), Value::Array(y)) => {
            for (i, (v, w)) in x.iter().zip(y).enumerate() {
                if let Some(d) = differ(v, w, format!("{path}[{i}]")) {
                    return Some(d);
                }
            }
            (x.len() != y.len()).then(|| format!("{path}: {} ≠ {} entries", x.len(), y.len()))
        }
        _ => (a != b).then(|| format!("{}: {} ≠ {}", if path.is_empty() { "(spec)" } else { &path }, short(a), short(b))),
    }
}

/// A value as JSON text, cut to 60 characters.
fn short(v: &Value) -> String {
    let s = v.to_string();
    match s.char_indices().nth(60) {
        Some((i, _)) => format!("{}…", &s[..i]),
        None => s,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spec::Driver;
    use crate::system::SequentialSystem;

    fn next_up(x: f64) -> f64 {
        f64::from_bits(if x >= 0.0 { x.to_bits() + 1 } else { x.to_bits() - 1 })
    }

    /// The identity survives what a platform's libm may change — the last bit of a solved value, or of a value a
    /// program computed — and still sees a change of a prescription value or of a rule.
    #[test]
    fn the_prescription_hash_ignores_the_last_bit_and_sees_a_real_change() {
        let spec = crate::presets::spec("sp").unwrap();
        let built = SequentialSystem::build(&spec).unwrap().spec;
        let h = system_sha256(&built).unwrap();
        assert_eq!(h.len(), 64);
        assert_eq!(system_sha256(&spec).unwrap(), h, "a spec and the system built from it are one prescription");
        let solved = built.surfaces.iter().position(|s| s.decenter_x_mm.as_ref().is_some_and(|c| c.driver == Driver::ChiefRay)).expect("SP solves a decenter for its chief ray");
        fn cell(s: &mut SystemSpec, i: usize) -> &mut crate::spec::Cell {
            s.surfaces[i].decenter_x_mm.as_mut().unwrap()
        }
        let mut moved = built.clone();
        let x = cell(&mut moved, solved).value;
        assert!(x.abs() > 1.0, "SP's solved decenter {x}");
        cell(&mut moved, solved).value = next_up(x);
        assert_eq!(system_sha256(&moved).unwrap(), h, "one ulp of a solved value");
        cell(&mut moved, solved).value = x + 1.0;
        assert_eq!(system_sha256(&moved).unwrap(), h, "a solved value is not the prescription: the build recomputes it");
        let plain = built.surfaces.iter().position(|s| s.thickness_mm.driver == Driver::Fixed && s.thickness_mm.value > 1.0).unwrap();
        let t = built.surfaces[plain].thickness_mm.value;
        let mut one_ulp = built.clone();
        one_ulp.surfaces[plain].thickness_mm.value = next_up(t);
        assert_eq!(system_sha256(&one_ulp).unwrap(), h, "one ulp of a plain value");
        assert_eq!(first_difference(&built, &one_ulp), None);
        let mut changed = built.clone();
        changed.surfaces[plain].thickness_mm.value = t * (1.0 + 1e-10);
        assert_ne!(system_sha256(&changed).unwrap(), h, "a change of 1e-10 relative is a change");
        let d = first_difference(&built, &changed).unwrap();
        assert!(d.starts_with(&format!("surfaces[{plain}].thickness_mm")) && d.contains("50.000000005"), "{d}");
        let mut unsolved = built.clone();
        cell(&mut unsolved, solved).driver = Driver::Fixed;
        assert_ne!(system_sha256(&unsolved).unwrap(), h, "dropping a solve is a change of the prescription");
        let mut renamed = built.clone();
        renamed.name = "sp2".into();
        assert_ne!(system_sha256(&renamed).unwrap(), h);
    }

    #[test]
    fn prescription_rounds_to_twelve_digits_and_writes_minus_zero_as_zero() {
        let mut v = serde_json::json!({"a": -0.0, "b": 2.408245759790968, "c": 7, "d": {"value": 1.5, "pickup": {"surface": 2}}, "e": [1e-300, -3.0]});
        canonical(&mut v);
        assert_eq!(v.to_string(), r#"{"a":0.0,"b":2.40824575979,"c":7,"d":{"pickup":{"surface":2}},"e":[1e-300,-3.0]}"#);
    }
}
