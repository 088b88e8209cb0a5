//! A system's identity by its prescription: the SHA-256 of its spec's JSON ([`system_sha256`], the
//! fingerprint a learned reconstruction records of the system it was trained for: Python's
//! `diffcassi.unrolled.system_sha256` hashes the same text), and the first place two specs differ
//! ([`first_difference`], to say *what* differs when two fingerprints do not match).
//!
//! ```
//! use diffcassi::spec::{first_difference, system_sha256};
//! let sp = diffcassi::presets::spec("sp")?;
//! let mut moved = sp.clone();
//! moved.surfaces[2].thickness_mm.value += 0.5;
//! assert_ne!(system_sha256(&sp)?, system_sha256(&moved)?);
//! assert!(first_difference(&sp, &moved).unwrap().starts_with("surfaces[2].thickness_mm"));
//! assert_eq!(first_difference(&sp, &sp.clone()), None);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::{to_json, SystemSpec};
use crate::error::Result;
use serde_json::Value;

/// SHA-256 (hex) of the spec's JSON ([`to_json`]): equal for equal prescriptions (name included), written by
/// the same code on every platform (floats in their shortest round-trip form). Give it a built system's spec
/// ([`crate::system::SequentialSystem::spec`], as a render records it and Python's `System.to_json()` writes it):
/// there a solved cell holds its solved value, which a spec file may hold rounded.
pub fn system_sha256(spec: &SystemSpec) -> Result<String> {
    Ok(crate::io::sha256::sha256_hex(to_json(spec)?.as_bytes()))
}

/// The first field, in the spec's JSON order, where `a` and `b` differ, as `path: A ≠ B`
/// (`surfaces[2].thickness_mm.value: 10 ≠ 10.5`); `None` when their JSON is equal.
pub fn first_difference(a: &SystemSpec, b: &SystemSpec) -> Option<String> {
    let (a, b) = (serde_json::to_value(a).ok()?, serde_json::to_value(b).ok()?);
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
