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

/// Keywords that hold display, editor, file, coating, mechanical or optimisation-bookkeeping settings: they do
/// not change the geometry or the media of the sequential trace, so skipping them leaves the system identical.
/// Each one met is listed ([`super::ZmxImport::skipped`], `diffcassi info`, `import-zmx`).
pub const COSMETIC: &[&str] = &[
    "VERS", "PFIL", "LANG", "GFAC", "PUSH", "SDMA", "OMMA", "ROPD", "PICB", "POLS", "GLRS", "GSTD", "NSCD", "COFN",
    "BLNK", "FIMP", "HIDE", "MIRR", "SLAB", "POPS", "MEMA", "COAT", "MOFF", "DMFS",
    "FWGN", "FWGT", "WWGN", "WWGT", "AUTH", "DBDT", "SSID", "LUID",
];

/// What a skipped keyword is, for the listing.
pub fn cosmetic_reason(keyword: &str) -> &'static str {
    match keyword {
        "VERS" | "PFIL" | "LANG" | "AUTH" => "file and editor settings",
        "DBDT" => "stock-lens catalogue data (vendor part number, nominal values); the surfaces hold the lens",
        "GFAC" | "GLRS" | "GSTD" => "glass substitution and catalogue display settings",
        "PUSH" | "SDMA" | "OMMA" | "ROPD" | "PICB" | "POLS" | "NSCD" | "FIMP" => "system options with no effect on the sequential ray trace",
        "COFN" | "COAT" => "coating file / coating (diffcassi's sequential trace has no coatings from .zmx)",
        "BLNK" => "blank merit-function row",
        "HIDE" | "SLAB" | "POPS" | "MIRR" => "display settings of the surface (hide, label, physical optics, mirror drawing)",
        "MEMA" => "mechanical semi-diameter (drawing only)",
        "MOFF" => "unused multi-configuration operand row",
        "DMFS" => "default merit function settings",
        "SSID" | "LUID" => "OpticStudio's surface / lens identifier (bookkeeping)",
        "FWGN" | "FWGT" | "WWGN" | "WWGT" => "field / wavelength weights (optimisation only)",
        _ => "no optics",
    }
}

/// Whether an unindented record that is not a surface record follows the last `SURF` block. OpticStudio writes
/// records after the surfaces (`TOL`, `MNUM`, merit rows…), so a file that has them was not cut inside its
/// surfaces; false without `SURF`. A surface record ([`SURFACE_KEYWORDS`]: `GLAS`, `DISZ`, …) belongs to the
/// surface above it whatever its indentation (the reader gives every record after a `SURF` line to that
/// surface), so an unindented `GLAS F2` as the last line is the image's glass in a file cut there, exactly as
/// the indented one: it does not mark the end of the surfaces.
pub fn records_follow_surfaces(recs: &[Record]) -> bool {
    recs.iter()
        .rposition(|r| r.keyword == "SURF")
        .is_some_and(|k| recs[k + 1..].iter().any(|r| !r.indented && !SURFACE_KEYWORDS.contains(&r.keyword.as_str())))
}

/// A merit-function operand row (`REAY 13 2 0 1 0 0 22.54 0 0 0`): OpticStudio writes the Merit Function
/// Editor after the surfaces, one unindented record per row, a 4-character operand name and exactly ten
/// numbers. Optimisation targets, no optics: skipped and listed. `known_surface_keyword` excludes the keywords
/// a surface block may hold.
pub fn is_merit_row(r: &Record, after_surfaces: bool, known_surface_keyword: bool) -> bool {
    after_surfaces
        && !r.indented
        && !known_surface_keyword
        && r.keyword.len() == 4
        && r.keyword.chars().all(|c| c.is_ascii_uppercase() || c.is_ascii_digit())
        && r.args.len() == 10
        && r.args.iter().all(|a| a.parse::<f64>().is_ok())
}

/// Keywords a surface block holds (read, refused or skipped by [`super::surfaces`]): never taken for a merit row.
pub const SURFACE_KEYWORDS: &[&str] = &[
    "TYPE", "STOP", "COMM", "CURV", "DISZ", "GLAS", "CONI", "PARM", "XDAT", "DIAM", "CLAP", "SQAP", "ELAP", "OBSC", "OBDC", "FLAP",
    "VCUR", "VDSZ", "VCON", "VPAR", "DCVR", "DCCR", "DCPK", "PZUP", "PPAR", "CUPP", "TPUP", "TSOL", "PSOL", "SSOL", "SCBD", "TILT",
    "DECX", "DECY", "MAZH",
];

/// The number of arguments OpticStudio writes for keywords that carry no optics and often end a file (`MNUM 1 1`,
/// `MOFF`, below). A last record without a line break that has fewer is a record cut in
/// the middle. Keywords read for their values need what their reader needs (a missing argument is refused
/// anyway).
///
/// `MOFF`: OpticStudio 16 and later write 12 arguments (`MOFF 0 1 "" 0 0 0 1 1 0 0.0 "" 0`), Zemax 12–14 wrote
/// 11 (no last `0`: the fixtures `cylinder_thorlabs_LJ1598L1.zmx`, VERS 120928, which ends there without a line
/// break, and `double_gauss_US583336.zmx`, VERS 140730); the fewer is the complete record.
pub fn written_arity(keyword: &str) -> Option<usize> {
    match keyword {
        "MNUM" => Some(2),
        "MOFF" => Some(11),
        "POPS" => Some(16),
        "MEMA" | "DIAM" => Some(6),
        "TOL" => Some(8),
        _ => None,
    }
}

/// A record's numeric argument `k` (0-based), or a message naming the line, keyword and text.
pub fn num(r: &Record, k: usize) -> Result<f64, String> {
    let t = r.args.get(k).ok_or_else(|| format!("line {} `{}`: argument {} missing (a truncated record)", r.line, r.keyword, k + 1))?;
    // Only the word INFINITY (as OpticStudio writes an infinite radius or object distance) is infinite. Rust's
    // parser also reads `inf` and an overflowing `1e999` as infinity: `DISZ 1e999` on the object was an object
    // at infinity while `DISZ 1e7` was refused as out of range. Those are refused here, naming the text.
    let v = if t.eq_ignore_ascii_case("INFINITY") || t.eq_ignore_ascii_case("+INFINITY") {
        f64::INFINITY
    } else if t.eq_ignore_ascii_case("-INFINITY") {
        f64::NEG_INFINITY
    } else {
        let v = t.parse::<f64>().map_err(|_| format!("line {} `{}`: argument {} `{t}` is not a number", r.line, r.keyword, k + 1))?;
        if v.is_infinite() {
            return Err(format!(
                "line {} `{}`: argument {} `{t}` is not finite ({}); only the word INFINITY means infinity, as OpticStudio writes it",
                r.line,
                r.keyword,
                k + 1,
                if t.chars().any(|c| c.is_ascii_digit()) { "it overflows the range of a double" } else { "not the word INFINITY" }
            ));
        }
        v
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
        return Err(format!("line {} `{}`: argument {} = {} is not an integer", r.line, r.keyword, k + 1, crate::limits::fmt_num(v)));
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

/// System-data records OpticStudio writes once (a second one is refused, naming both lines): the reader would
/// keep one of the two silently. `NOTE` (OpticStudio writes several `NOTE 0` lines), `DCGC` (one per
/// catalogue file) and the records without optics are not among them.
const HEADER_ONCE: &[&str] = &[
    "NAME", "MODE", "UNIT", "RAIM", "ENVD", "FTYP", "XFLN", "YFLN", "XFLD", "YFLD", "VDXN", "VDYN", "VCXN", "VCYN", "VANN", "VDXF",
    "VDYF", "VCXF", "VCYF", "VANF", "WAVL", "WWGT", "PWAV", "GCAT", "DCAI", "DCWP", "MNUM",
];
/// The system aperture records: one of them, once (`ENPD 10` with `FNUM 5 0` took the F/# silently).
pub const APERTURE_RECORDS: &[&str] = &["ENPD", "FNUM", "OBNA", "FLOA"];
/// Surface records a surface holds once.
const SURFACE_ONCE: &[&str] = &["TYPE", "STOP", "COMM", "CURV", "DISZ", "GLAS", "CONI", "DIAM", "CLAP", "SQAP", "OBSC", "OBDC", "FLAP", "DCGE", "VCUR", "VDSZ", "VCON"];
/// Surface records indexed by their first argument (`PARM 1 …`, `XDAT 2 …`, `VPAR 3`, diffcassi's `DCPK column …`):
/// once per index; several indices are how OpticStudio writes them.
const SURFACE_INDEXED: &[&str] = &["PARM", "XDAT", "VPAR", "DCVR", "DCCR", "DCPK"];

/// What a record defines that may be defined once — `None` for records that may repeat. The scope is the
/// system data (`Some((None, key))`) or the surface being read (`Some((Some(surface), key))`); `surface` is the
/// surface the record belongs to, if any. The same key twice in one scope is refused by the importer, naming
/// both lines: OpticStudio writes each once, and taking the first or the last silently (as the reader did:
/// the last `CURV`, the first `WAVM 1`) is a guess.
pub fn once_key(r: &Record, surface: Option<usize>) -> Option<(Option<usize>, String)> {
    let kw = r.keyword.as_str();
    let first = || r.args.first().cloned().unwrap_or_default();
    if APERTURE_RECORDS.contains(&kw) {
        return Some((None, "the system aperture".into()));
    }
    if HEADER_ONCE.contains(&kw) {
        // Two spellings of one list (`XFLN`/`XFLD` the x fields, `YFLN`/`YFLD` the y fields, `VDXN`/`VDXF`… a
        // vignetting column; the `…D`/`…F` ones from older files): one key, so that `YFLN` then `YFLD` is refused
        // as a list given twice (the later one replaced the first silently).
        let canonical = match kw {
            "XFLD" => "XFLN",
            "YFLD" => "YFLN",
            k if k.len() == 4 && k.starts_with('V') && k.ends_with('F') => &k[..3],
            k => k,
        };
        let alias = (canonical.len() == 3).then(|| format!("{canonical}N"));
        return Some((None, format!("`{}`", alias.as_deref().unwrap_or(canonical))));
    }
    if kw == "WAVM" {
        return Some((None, format!("wavelength {}", first())));
    }
    let s = surface?;
    if SURFACE_ONCE.contains(&kw) {
        return Some((Some(s), format!("`{kw}`")));
    }
    if SURFACE_INDEXED.contains(&kw) {
        return Some((Some(s), format!("`{kw} {}`", first())));
    }
    None
}
