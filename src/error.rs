//! The crate's error type. Every message names what was wrong: the file, the line or field, the value.
use crate::materials::MaterialError;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A spec (TOML/JSON/YAML/CSV prescription) could not be read or is invalid.
    #[error("{source_name}: {}", tidy(message))]
    Spec { source_name: String, message: String },
    /// A built system is inconsistent (message names surface and field).
    #[error("system `{system}`: surface {surface} ({field}): {}", tidy(message))]
    System { system: String, surface: usize, field: String, message: String },
    #[error(transparent)]
    Material(#[from] MaterialError),
    #[error("{path}: {}", tidy(message))]
    File { path: String, message: String },
    #[error("{}", tidy(.0))]
    Invalid(String),
    #[error(transparent)]
    Io(#[from] crate::io::IoError),
    #[error(transparent)]
    Plot(#[from] crate::plot::PlotError),
    /// The computation was stopped by its [`crate::cancel::Cancel`] token (Ctrl-C in Python); nothing was returned.
    #[error("interrupted: the computation was cancelled before it finished (nothing was returned)")]
    Interrupted,
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    pub fn spec(source_name: impl Into<String>, message: impl Into<String>) -> Self {
        Error::Spec { source_name: source_name.into(), message: message.into() }
    }
    pub fn invalid(message: impl Into<String>) -> Self {
        Error::Invalid(message.into())
    }
}

/// A message as the process's front end reads it: [`tidy_numbers`], then the settings spelled as that front end
/// names them ([`crate::frontend::spell`]: `--rays` is Python's `rays`, C++'s `RenderOptions::rays_per_pixel`).
fn tidy(text: &str) -> std::borrow::Cow<'_, str> {
    let frontend = crate::frontend::current();
    match tidy_numbers(text) {
        std::borrow::Cow::Borrowed(b) => crate::frontend::spell(b, frontend),
        std::borrow::Cow::Owned(o) => std::borrow::Cow::Owned(crate::frontend::spell(&o, frontend).into_owned()),
    }
}

/// `text` with every decimal number of more than 21 digits, and every decimal fraction below 1e-4 in
/// magnitude (not 0), rewritten in exponent form (`1e-300`, not 300 zeros; `1e-20`, not 20): Rust's `{}` never
/// writes an exponent, so a value given as `1e-300` would come back as a 302-character number in a message.
/// The fraction bound is [`crate::limits::fmt_num`]'s, so a number reads the same whether its message
/// formatted it with `fmt_num` or with `{}` (`PARM 9 1e-20` was refused as `0.00000000000000000001`, 21
/// digits, one short of the old bound, while `1e-300` was printed short; round 19). The rewrite is exact
/// (shortest round-trip digits in both forms); a digit run that touches a letter, an underscore or a path
/// separator (a hex digest, a name, a folder) is left as it is, and so are integers up to 21 digits (every
/// u64 seed).
pub fn tidy_numbers(text: &str) -> std::borrow::Cow<'_, str> {
    const MAX_DIGITS: usize = 21;
    let b = text.as_bytes();
    let is_word = |c: u8| c.is_ascii_alphabetic() || matches!(c, b'_' | b'/' | b'\\');
    let mut out: Option<String> = None;
    let (mut copied, mut i) = (0, 0);
    while i < b.len() {
        if !b[i].is_ascii_digit() {
            i += 1;
            continue;
        }
        let start = i;
        while i < b.len() && (b[i].is_ascii_digit() || (b[i] == b'.' && i + 1 < b.len() && b[i + 1].is_ascii_digit())) {
            i += 1;
        }
        let run = &text[start..i];
        let digits = run.bytes().filter(u8::is_ascii_digit).count();
        let touches_word = (start > 0 && (is_word(b[start - 1]) || b[start - 1] == b'.')) || (i < b.len() && is_word(b[i]));
        let small_fraction = || run.contains('.') && run.parse::<f64>().is_ok_and(|v| v != 0.0 && v.abs() < 1e-4);
        if (digits > MAX_DIGITS || small_fraction()) && !touches_word {
            if let Ok(v) = run.parse::<f64>() {
                if v.is_finite() {
                    let o = out.get_or_insert_with(String::new);
                    o.push_str(&text[copied..start]);
                    o.push_str(&format!("{v:e}"));
                    copied = i;
                }
            }
        }
    }
    match out {
        None => std::borrow::Cow::Borrowed(text),
        Some(mut o) => {
            o.push_str(&text[copied..]);
            std::borrow::Cow::Owned(o)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_numbers_in_messages_take_the_exponent_form() {
        let tiny = format!("--tolerance-um {}: too small", 1e-30f64);
        assert_eq!(Error::invalid(tiny).to_string(), "--tolerance-um 1e-30: too small");
        let huge = format!("value {} and {}", 1.7e308f64, -2.5e25f64);
        assert_eq!(Error::invalid(huge).to_string(), "value 1.7e308 and -2.5e25");
        assert_eq!(Error::spec("a.toml", format!("radius {}", 1e-300f64)).to_string(), "a.toml: radius 1e-300");
        // Left alone: ordinary numbers, a u64 seed, digests, names with digits.
        let kept = "seed 18446744073709551615, pitch 0.01 mm, 1e-30, sha 0123456789012345678901234567890123abc, x_12345678901234567890123, /tmp/12345678901234567890123/f";
        assert_eq!(Error::invalid(kept).to_string(), kept);
        // The rewrite is exact: the exponent form parses back to the same f64.
        // A fraction below fmt_num's 1e-4 takes the exponent form at any length (1e-20 is 21 digits, not 22);
        // 1e-4 and above, and 0, stay as written.
        assert_eq!(Error::invalid(format!("parameter 9 = {} and {}", 1e-20f64, -3e-5f64)).to_string(), "parameter 9 = 1e-20 and -3e-5");
        assert_eq!(Error::invalid("0.0001 0.5 0.000000 10.00001").to_string(), "0.0001 0.5 0.000000 10.00001");
        let v = 1.234567890123456789e-25f64;
        let msg = Error::invalid(format!("{v}")).to_string();
        assert!(msg.contains('e') && msg.parse::<f64>().unwrap() == v, "{msg}");
    }
}
