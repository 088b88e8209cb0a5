//! Which `.zmx` keywords diffcassi reads, which it may skip because they do not change the traced system,
//! and which it refuses (reported by line and keyword).
use super::lexer::Record;

/// A keyword of the file that diffcassi does not model.
#[derive(Clone, Debug, PartialEq)]
pub struct Unsupported {
    pub line: usize,
    pub keyword: String,
    pub reason: String,
}

impl std::fmt::Display for Unsupported {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(f, "line {} `{}`: {}", self.line, self.keyword, self.reason)
    }
}

/// Keywords that hold display, file, coating, mechanical or optimisation-bookkeeping settings: they do not
/// change the geometry or the media of the sequential trace, so skipping them leaves the system identical.
pub const COSMETIC: &[&str] = &[
    "VERS", "PFIL", "LANG", "GFAC", "PUSH", "SDMA", "OMMA", "ROPD", "PICB", "POLS", "GLRS", "GSTD", "NSCD", "COFN",
    "BLNK", "FIMP", "HIDE", "MIRR", "SLAB", "POPS", "MEMA", "COAT", "MOFF", "DMFS",
    "FWGN", "FWGT", "WWGN", "WWGT",
];

/// A record's numeric argument `k` (0-based), or a message naming the line, keyword and text.
pub fn num(r: &Record, k: usize) -> Result<f64, String> {
    let t = r.args.get(k).ok_or_else(|| format!("line {} `{}`: argument {} missing (a truncated record)", r.line, r.keyword, k + 1))?;
    let v = if t.eq_ignore_ascii_case("INFINITY") || t.eq_ignore_ascii_case("INF") {
        f64::INFINITY
    } else if t.eq_ignore_ascii_case("-INFINITY") || t.eq_ignore_ascii_case("-INF") {
        f64::NEG_INFINITY
    } else {
        t.parse::<f64>().map_err(|_| format!("line {} `{}`: argument {} `{t}` is not a number", r.line, r.keyword, k + 1))?
    };
    if v.is_nan() {
        return Err(format!("line {} `{}`: argument {} is NaN", r.line, r.keyword, k + 1));
    }
    Ok(v)
}

/// A finite numeric argument.
pub fn finite(r: &Record, k: usize) -> Result<f64, String> {
    let v = num(r, k)?;
    if !v.is_finite() {
        return Err(format!("line {} `{}`: argument {} = {v} is not finite", r.line, r.keyword, k + 1));
    }
    Ok(v)
}

/// An integer argument.
pub fn int(r: &Record, k: usize) -> Result<i64, String> {
    let v = finite(r, k)?;
    if v.fract() != 0.0 || v.abs() > 1e9 {
        return Err(format!("line {} `{}`: argument {} = {v} is not an integer", r.line, r.keyword, k + 1));
    }
    Ok(v as i64)
}

/// An optional numeric argument (absent → `default`).
pub fn num_or(r: &Record, k: usize, default: f64) -> Result<f64, String> {
    if r.args.len() > k {
        num(r, k)
    } else {
        Ok(default)
    }
}
