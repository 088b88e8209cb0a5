//! Parser for Zemax OpticStudio `.AGF` glass catalogues.
//!
//! An AGF file is line oriented; the first token of a line names the record:
//!
//! | record | content | handling |
//! |--------|---------|----------|
//! | `CC` | catalogue comment | kept in [`AgfDocument::comments`] |
//! | `NM` | `name formula MIL nd vd [exclude [status [melt]]]` — starts a glass | strict |
//! | `GC` | glass comment | kept in [`GlassInfo::comment`](super::GlassInfo::comment) |
//! | `ED` | `TCE(−30..70) TCE(100..300) density ΔPgF ignore_thermal_expansion` | lenient, kept |
//! | `CD` | dispersion coefficients (in the order of [`DispersionFormula`]) | strict |
//! | `TD` | `D0 D1 D2 E0 E1 λtk Tref` | lenient, kept, not applied |
//! | `LD` | `min max` wavelength in µm | strict, required |
//! | `IT` | `λ(µm) transmission thickness(mm)` | lenient, kept |
//! | `OD`, `MD`, `BD`, others | — | ignored |
//!
//! *Strict* records determine the refractive index: a missing or malformed value is an
//! [`MaterialError::AgfParse`] error naming the source, the 1-based line and the glass.
//! *Lenient* records are informative: the placeholders `_` and `-` (which SCHOTT.AGF uses)
//! and missing trailing values are accepted; a token that is neither a number nor a
//! placeholder is still an error. A `TD` record with fewer than 7 values (SCHOTT.AGF has
//! empty ones) gives [`Glass::thermal`] = `None`.
//!
//! Further rules: every glass needs one `CD` and one `LD` record; record lines other than
//! `CC` before the first `NM` are errors; glass names must be unique case-insensitively;
//! the formula number must be 1..=13; `CD` may hold more values than the formula needs
//! (SCHOTT pads to 8 or 10 with zeros; extras are ignored) but not fewer.
//!
//! Text encodings: UTF-8 (with or without BOM), UTF-16 LE/BE with BOM (Zemax writes
//! UTF-16 LE), BOM-less UTF-16 recognised from a zero byte in the first code unit, and any
//! non-UTF-8 byte text decoded as Windows-1252 — the `.zmx` reader's rule
//! ([`crate::spec::zmx::lexer::decode_windows_1252`]), so a glass name with a byte in 0x80–0x9F reads the
//! same in a lens file and its catalogue. Line ends as in a `.zmx` file
//! ([`crate::spec::zmx::lexer::unify_line_ends`]): CRLF, LF and a CR alone each end a record, in any mix
//! and in every encoding.
//!
//! # Example
//!
//! ```
//! use diffcassi::materials::parse_agf;
//!
//! let text = "CC demo catalogue\r\n\
//!             NM MYGLASS 2 517642.251 1.5168 64.17 0 1\r\n\
//!             CD 1.03961212 6.00069867E-03 2.31792344E-01 2.00179144E-02 1.01046945 103.560653\r\n\
//!             LD 0.3 2.5\r\n";
//! let glasses = parse_agf(text, "DEMO.AGF")?;
//! assert_eq!(glasses.len(), 1);
//! assert_eq!(glasses[0].catalog, "DEMO");
//! assert_eq!(glasses[0].min_wavelength_nm, 300.0);
//! assert!((glasses[0].refractive_index(587.5618)? - 1.5168).abs() < 1e-4);
//!
//! let bad = parse_agf("NM X 2 0 1.5 60\nCD 1.0 abc\n", "BAD.AGF").unwrap_err();
//! assert!(bad.to_string().starts_with("BAD.AGF:2:"));
//! # Ok::<(), diffcassi::materials::MaterialError>(())
//! ```

use std::borrow::Cow;
use std::collections::HashMap;
use std::path::Path;

use super::dispersion::DispersionFormula;
use super::glass::{ExtraData, Glass, GlassInfo, GlassStatus, ThermalData, TransmissionPoint};
use super::MaterialError;

/// A parsed AGF catalogue.
#[derive(Clone, Debug, PartialEq)]
pub struct AgfDocument {
    /// Catalogue name: file stem of the source name, upper case (`"SCHOTT"`).
    pub catalog: String,
    /// `CC` comment lines, trimmed, in file order.
    pub comments: Vec<String>,
    /// Glasses in file order.
    pub glasses: Vec<Glass>,
}

/// Parses AGF text (or raw bytes in any supported encoding) into glasses, in file order.
///
/// `source_name` (file name or path) is used in error messages and, through its file
/// stem, as [`Glass::catalog`].
///
/// # Errors
/// [`MaterialError::AgfParse`] naming `source_name` and the 1-based line,
/// [`MaterialError::Encoding`] for undecodable bytes.
pub fn parse_agf(input: impl AsRef<[u8]>, source_name: &str) -> Result<Vec<Glass>, MaterialError> {
    parse_agf_document(input, source_name).map(|doc| doc.glasses)
}

/// Like [`parse_agf`] but also returns the catalogue name and `CC` comments.
pub fn parse_agf_document(
    input: impl AsRef<[u8]>,
    source_name: &str,
) -> Result<AgfDocument, MaterialError> {
    let text = decode_agf_bytes(input.as_ref(), source_name)?;
    Parser::new(source_name).run(&text)
}

/// Catalogue name derived from a source name: file stem in upper case
/// (`"/x/schott.agf"` → `"SCHOTT"`).
pub fn catalog_name_from_source(source_name: &str) -> String {
    Path::new(source_name)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| source_name.to_string())
        .to_uppercase()
}

/// Decodes catalogue bytes to text: BOM-detected UTF-8 / UTF-16 LE / UTF-16 BE,
/// BOM-less UTF-16 (zero byte in the first code unit), else UTF-8, falling back to
/// Windows-1252 for byte sequences that are not valid UTF-8 (as the `.zmx` reader does). Every line end
/// of the result is LF: CRLF and a CR alone are line ends too, as in a `.zmx` file.
///
/// # Errors
/// [`MaterialError::Encoding`] for UTF-16 input with an odd number of bytes.
pub fn decode_agf_bytes<'a>(
    bytes: &'a [u8],
    source_name: &str,
) -> Result<Cow<'a, str>, MaterialError> {
    let text = decode_agf_encoding(bytes, source_name)?;
    Ok(if text.contains('\r') {
        Cow::Owned(crate::spec::zmx::lexer::unify_line_ends(text.into_owned()))
    } else {
        text
    })
}

fn decode_agf_encoding<'a>(
    bytes: &'a [u8],
    source_name: &str,
) -> Result<Cow<'a, str>, MaterialError> {
    if let Some(rest) = bytes.strip_prefix(&[0xEF, 0xBB, 0xBF]) {
        return Ok(utf8_or_windows_1252(rest));
    }
    if let Some(rest) = bytes.strip_prefix(&[0xFF, 0xFE]) {
        return decode_utf16(rest, false, source_name).map(Cow::Owned);
    }
    if let Some(rest) = bytes.strip_prefix(&[0xFE, 0xFF]) {
        return decode_utf16(rest, true, source_name).map(Cow::Owned);
    }
    if bytes.len() >= 2 {
        if bytes[0] != 0 && bytes[1] == 0 {
            return decode_utf16(bytes, false, source_name).map(Cow::Owned);
        }
        if bytes[0] == 0 && bytes[1] != 0 {
            return decode_utf16(bytes, true, source_name).map(Cow::Owned);
        }
    }
    Ok(utf8_or_windows_1252(bytes))
}

fn utf8_or_windows_1252(bytes: &[u8]) -> Cow<'_, str> {
    match std::str::from_utf8(bytes) {
        Ok(s) => Cow::Borrowed(s),
        Err(_) => Cow::Owned(crate::spec::zmx::lexer::decode_windows_1252(bytes)),
    }
}

fn decode_utf16(
    bytes: &[u8],
    big_endian: bool,
    source_name: &str,
) -> Result<String, MaterialError> {
    if bytes.len() % 2 != 0 {
        return Err(MaterialError::Encoding {
            source_name: source_name.to_string(),
            message: format!("UTF-16 text has an odd number of bytes ({})", bytes.len()),
        });
    }
    let units = bytes.chunks_exact(2).map(|b| {
        if big_endian {
            u16::from_be_bytes([b[0], b[1]])
        } else {
            u16::from_le_bytes([b[0], b[1]])
        }
    });
    let mut text: String = char::decode_utf16(units)
        .map(|r| r.unwrap_or(char::REPLACEMENT_CHARACTER))
        .collect();
    if text.starts_with('\u{FEFF}') {
        text.remove(0);
    }
    Ok(text)
}

/// A glass whose records are still being collected.
struct Pending {
    name: String,
    nm_line: usize,
    formula: u32,
    nd: f64,
    vd: f64,
    info: GlassInfo,
    cd: Option<(Vec<f64>, usize)>,
    ld: Option<(f64, f64, usize)>,
    thermal: Option<ThermalData>,
}

struct Parser<'s> {
    source_name: &'s str,
    catalog: String,
    comments: Vec<String>,
    glasses: Vec<Glass>,
    /// Upper-case name → NM line, for duplicate detection.
    seen: HashMap<String, usize>,
    current: Option<Pending>,
}

fn is_placeholder(tok: &str) -> bool {
    tok == "_" || tok == "-"
}

/// Strict finite f64.
fn number(tok: &str) -> Option<f64> {
    tok.parse::<f64>().ok().filter(|v| v.is_finite())
}

impl<'s> Parser<'s> {
    fn new(source_name: &'s str) -> Self {
        Self {
            source_name,
            catalog: catalog_name_from_source(source_name),
            comments: Vec::new(),
            glasses: Vec::new(),
            seen: HashMap::new(),
            current: None,
        }
    }

    fn err(&self, line: usize, message: impl Into<String>) -> MaterialError {
        MaterialError::AgfParse {
            source_name: self.source_name.to_string(),
            line,
            message: message.into(),
        }
    }

    fn run(mut self, text: &str) -> Result<AgfDocument, MaterialError> {
        let text = text.strip_prefix('\u{FEFF}').unwrap_or(text);
        // `text` comes from `decode_agf_bytes`: every line end is LF (CRLF and a lone CR included).
        for (idx, raw) in text.lines().enumerate() {
            // A catalogue is text: control characters (other than tab, form feed and the DOS end-of-file
            // mark; C1 controls included, as the `.zmx` reader refuses them: the five bytes Windows-1252 leaves
            // undefined) or decoding replacement characters mean a binary or corrupt file, not records to skip.
            if let Some(c) = raw.chars().find(|&c| (c.is_control() && !matches!(c, '\t' | '\x0c' | '\x1a')) || c == char::REPLACEMENT_CHARACTER) {
                return Err(self.err(idx + 1, format!("not an AGF text file: byte/character U+{:04X} (binary or corrupt data)", c as u32)));
            }
            self.line(idx + 1, raw)?;
        }
        self.finish_current()?;
        if self.glasses.is_empty() {
            return Err(self.err(
                text.lines().count().max(1),
                "no glass (NM record) in the file: not an AGF catalogue, or an empty one",
            ));
        }
        Ok(AgfDocument {
            catalog: self.catalog,
            comments: self.comments,
            glasses: self.glasses,
        })
    }

    fn line(&mut self, line: usize, raw: &str) -> Result<(), MaterialError> {
        let trimmed = raw.trim();
        let mut tokens = trimmed.split_whitespace();
        let Some(keyword) = tokens.next() else {
            return Ok(());
        };
        let keyword = keyword.to_ascii_uppercase();
        let rest_text = trimmed[keyword.len()..].trim();
        let args: Vec<&str> = tokens.collect();
        match keyword.as_str() {
            "CC" => {
                self.comments.push(rest_text.to_string());
                Ok(())
            }
            "NM" => {
                self.finish_current()?;
                self.nm(line, &args)
            }
            "GC" | "ED" | "CD" | "TD" | "LD" | "IT" => {
                let Some(mut cur) = self.current.take() else {
                    return Err(self.err(
                        line,
                        format!("{keyword} record before any NM record (no glass to attach it to)"),
                    ));
                };
                let result = match keyword.as_str() {
                    "GC" => {
                        cur.info.comment = rest_text.to_string();
                        Ok(())
                    }
                    "ED" => self.ed(line, &args, &mut cur),
                    "CD" => self.cd(line, &args, &mut cur),
                    "TD" => self.td(line, &args, &mut cur),
                    "LD" => self.ld(line, &args, &mut cur),
                    _ => self.it(line, &args, &mut cur),
                };
                self.current = Some(cur);
                result
            }
            // OD, MD, BD and unknown records are ignored.
            _ => Ok(()),
        }
    }

    fn nm(&mut self, line: usize, args: &[&str]) -> Result<(), MaterialError> {
        if args.len() < 5 {
            return Err(self.err(
                line,
                format!(
                    "NM record needs at least 5 fields (name formula MIL nd vd), found {}",
                    args.len()
                ),
            ));
        }
        let name = args[0].to_string();
        let key = name.to_uppercase();
        if let Some(&first) = self.seen.get(&key) {
            return Err(self.err(
                line,
                format!(
                    "duplicate glass name {name} (case-insensitive; first defined at line {first})"
                ),
            ));
        }
        let formula_tok = args[1];
        let formula = match number(formula_tok) {
            Some(v) if v.fract() == 0.0 && (1.0..=13.0).contains(&v) => v as u32,
            Some(v) if v.fract() == 0.0 && v.abs() < 1e9 => {
                return Err(self.err(
                    line,
                    MaterialError::UnsupportedFormula {
                        glass: name,
                        formula: v as i64,
                    }
                    .to_string(),
                ))
            }
            _ => {
                return Err(self.err(
                    line,
                    format!("glass {name}: invalid dispersion formula number '{formula_tok}'"),
                ))
            }
        };
        let nd = number(args[3]).ok_or_else(|| {
            self.err(
                line,
                format!("glass {name}: invalid nd '{}' in NM record", args[3]),
            )
        })?;
        let vd = number(args[4]).ok_or_else(|| {
            self.err(
                line,
                format!("glass {name}: invalid vd '{}' in NM record", args[4]),
            )
        })?;
        let int_field = |idx: usize, what: &str| -> Result<Option<i64>, MaterialError> {
            match args.get(idx) {
                None => Ok(None),
                Some(t) if is_placeholder(t) => Ok(None),
                Some(t) => match number(t) {
                    Some(v) if v.fract() == 0.0 && v.abs() < 1e9 => Ok(Some(v as i64)),
                    _ => Err(self.err(
                        line,
                        format!("glass {name}: invalid {what} '{t}' in NM record"),
                    )),
                },
            }
        };
        let exclude = int_field(5, "exclude-substitution flag")?;
        let status = int_field(6, "status")?;
        let melt = int_field(7, "melt frequency")?;
        let info = GlassInfo {
            mil_code: args[2].to_string(),
            exclude_substitution: exclude.is_some_and(|v| v != 0),
            status: status.and_then(GlassStatus::from_code),
            melt_frequency: melt,
            ..GlassInfo::default()
        };
        self.seen.insert(key, line);
        self.current = Some(Pending {
            name,
            nm_line: line,
            formula,
            nd,
            vd,
            info,
            cd: None,
            ld: None,
            thermal: None,
        });
        Ok(())
    }

    fn cd(&self, line: usize, args: &[&str], cur: &mut Pending) -> Result<(), MaterialError> {
        if let Some((_, first)) = &cur.cd {
            return Err(self.err(
                line,
                format!(
                    "glass {}: second CD record (first at line {first})",
                    cur.name
                ),
            ));
        }
        let mut values = Vec::with_capacity(args.len());
        for (i, tok) in args.iter().enumerate() {
            let v = number(tok).ok_or_else(|| {
                self.err(
                    line,
                    format!(
                        "glass {}: invalid number '{tok}' for dispersion coefficient {} in CD record",
                        cur.name,
                        i + 1
                    ),
                )
            })?;
            values.push(v);
        }
        cur.cd = Some((values, line));
        Ok(())
    }

    fn ld(&self, line: usize, args: &[&str], cur: &mut Pending) -> Result<(), MaterialError> {
        if let Some((_, _, first)) = &cur.ld {
            return Err(self.err(
                line,
                format!(
                    "glass {}: second LD record (first at line {first})",
                    cur.name
                ),
            ));
        }
        if args.len() < 2 {
            return Err(self.err(
                line,
                format!(
                    "glass {}: LD record needs 2 values (min max wavelength in µm), found {}",
                    cur.name,
                    args.len()
                ),
            ));
        }
        let mut v = [0.0; 2];
        for (slot, tok) in v.iter_mut().zip(args) {
            *slot = number(tok).ok_or_else(|| {
                self.err(
                    line,
                    format!(
                        "glass {}: invalid wavelength '{tok}' in LD record",
                        cur.name
                    ),
                )
            })?;
        }
        let [min_um, max_um] = v;
        if !(min_um > 0.0 && max_um > min_um) {
            return Err(self.err(
                line,
                format!(
                    "glass {}: invalid LD wavelength range [{}, {}] µm (need 0 < min < max)",
                    cur.name,
                    crate::limits::fmt_num(min_um),
                    crate::limits::fmt_num(max_um)
                ),
            ));
        }
        cur.ld = Some((min_um, max_um, line));
        Ok(())
    }

    /// Lenient numeric fields: placeholders → `None`, garbage → error.
    fn lenient(
        &self,
        line: usize,
        record: &str,
        args: &[&str],
        cur: &Pending,
    ) -> Result<Vec<Option<f64>>, MaterialError> {
        args.iter()
            .map(|tok| {
                if is_placeholder(tok) {
                    Ok(None)
                } else {
                    number(tok).map(Some).ok_or_else(|| {
                        self.err(
                            line,
                            format!(
                                "glass {}: invalid number '{tok}' in {record} record",
                                cur.name
                            ),
                        )
                    })
                }
            })
            .collect()
    }

    fn ed(&self, line: usize, args: &[&str], cur: &mut Pending) -> Result<(), MaterialError> {
        let v = self.lenient(line, "ED", args, cur)?;
        let get = |i: usize| v.get(i).copied().flatten();
        cur.info.extra = Some(ExtraData {
            tce_minus30_70: get(0),
            tce_100_300: get(1),
            density_g_cm3: get(2),
            delta_pg_f: get(3),
            ignore_thermal_expansion: get(4).map(|x| x != 0.0),
        });
        Ok(())
    }

    fn td(&self, line: usize, args: &[&str], cur: &mut Pending) -> Result<(), MaterialError> {
        let v = self.lenient(line, "TD", args, cur)?;
        cur.thermal = match v.as_slice() {
            [Some(d0), Some(d1), Some(d2), Some(e0), Some(e1), Some(ltk), Some(tref), ..] => {
                Some(ThermalData {
                    d0: *d0,
                    d1: *d1,
                    d2: *d2,
                    e0: *e0,
                    e1: *e1,
                    lambda_tk_um: *ltk,
                    reference_temperature_c: *tref,
                })
            }
            _ => None,
        };
        Ok(())
    }

    fn it(&self, line: usize, args: &[&str], cur: &mut Pending) -> Result<(), MaterialError> {
        let v = self.lenient(line, "IT", args, cur)?;
        if let [Some(w), Some(t), Some(d), ..] = v.as_slice() {
            cur.info.transmission.push(TransmissionPoint {
                wavelength_um: *w,
                transmission: *t,
                thickness_mm: *d,
            });
        }
        Ok(())
    }

    fn finish_current(&mut self) -> Result<(), MaterialError> {
        let Some(p) = self.current.take() else {
            return Ok(());
        };
        let Some((cd, cd_line)) = p.cd else {
            return Err(self.err(
                p.nm_line,
                format!(
                    "glass {} has no CD (dispersion coefficients) record",
                    p.name
                ),
            ));
        };
        let Some((min_um, max_um, _)) = p.ld else {
            return Err(self.err(
                p.nm_line,
                format!("glass {} has no LD (wavelength range) record", p.name),
            ));
        };
        let formula = DispersionFormula::from_agf(&p.name, p.formula, &cd)
            .map_err(|e| self.err(cd_line, e.to_string()))?;
        self.glasses.push(Glass {
            name: p.name,
            formula,
            nd: p.nd,
            vd: p.vd,
            min_wavelength_nm: min_um * 1000.0,
            max_wavelength_nm: max_um * 1000.0,
            catalog: self.catalog.clone(),
            thermal: p.thermal,
            info: p.info,
        });
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ONE: &str = "CC test catalogue\n\
NM N-BK7 2 517642.251 1.5168 64.17 0 1\n\
GC step 0.5 available      \n\
ED 7.100000 8.300000 2.510000 -0.000900 0  \n\
CD 1.039612120E+00 6.000698670E-03 2.317923440E-01 2.001791440E-02 1.010469450E+00 1.035606530E+02 0.000000000E+00 0.000000000E+00\n\
TD 1.860000E-06 1.310000E-08 -1.370000E-11 4.340000E-07 6.270000E-10 1.700000E-01 2.000000E+01\n\
OD 1.0 1.0 0.0 1.0 2.3 2.3 \n\
LD 3.00000E-01 2.50000E+00     \n\
IT 3.00000E-01 5.00000E-02 2.50000E+01    \n\
IT 3.10000E-01 2.50000E-01 2.50000E+01    \n";

    fn parse_err(text: &str) -> (String, usize, String) {
        match parse_agf(text, "T.AGF").unwrap_err() {
            MaterialError::AgfParse {
                source_name,
                line,
                message,
            } => (source_name, line, message),
            e => panic!("unexpected error {e:?}"),
        }
    }

    #[test]
    fn binary_or_empty_file_is_an_error_not_an_empty_catalogue() {
        let (src, line, msg) = parse_err("\x00\x01\x02ELF\x7f binary");
        assert_eq!(src, "T.AGF");
        assert!(msg.contains("not an AGF text file") && line == 1, "{line} {msg}");
        let bytes: Vec<u8> = (0..4096u32).map(|i| (i.wrapping_mul(2654435761) >> 13) as u8).collect();
        assert!(parse_agf(&bytes, "T.AGF").is_err());
        for text in ["", "CC only a comment\n", "XX some unknown record\n"] {
            let (_, _, msg) = parse_err(text);
            assert!(msg.contains("no glass"), "{text:?}: {msg}");
        }
    }

    #[test]
    fn parses_all_records() {
        let doc = parse_agf_document(ONE, "dir/schott.agf").unwrap();
        assert_eq!(doc.catalog, "SCHOTT");
        assert_eq!(doc.comments, vec!["test catalogue".to_string()]);
        let g = &doc.glasses[0];
        assert_eq!(g.name, "N-BK7");
        assert_eq!(g.formula.agf_number(), 2);
        assert_eq!(g.formula.coefficients()[5], 103.560653);
        assert_eq!((g.nd, g.vd), (1.5168, 64.17));
        assert_eq!((g.min_wavelength_nm, g.max_wavelength_nm), (300.0, 2500.0));
        assert_eq!(g.info.mil_code, "517642.251");
        assert_eq!(g.info.status, Some(GlassStatus::Preferred));
        assert!(!g.info.exclude_substitution);
        assert_eq!(g.info.comment, "step 0.5 available");
        assert_eq!(g.info.extra.unwrap().delta_pg_f, Some(-0.0009));
        assert_eq!(g.thermal.unwrap().reference_temperature_c, 20.0);
        assert_eq!(g.thermal.unwrap().lambda_tk_um, 0.17);
        assert_eq!(g.info.transmission.len(), 2);
        assert_eq!(g.info.transmission[1].transmission, 0.25);
    }

    #[test]
    fn crlf_and_utf8_bom() {
        let crlf = format!("\u{FEFF}{}", ONE.replace('\n', "\r\n"));
        let a = parse_agf(&crlf, "A.AGF").unwrap();
        let b = parse_agf(ONE, "A.AGF").unwrap();
        assert_eq!(a, b);
    }

    fn utf16(text: &str, big_endian: bool, bom: bool) -> Vec<u8> {
        let mut out = Vec::new();
        let units = bom
            .then_some(0xFEFFu16)
            .into_iter()
            .chain(text.encode_utf16());
        for u in units {
            out.extend_from_slice(&if big_endian {
                u.to_be_bytes()
            } else {
                u.to_le_bytes()
            });
        }
        out
    }

    #[test]
    fn utf16_le_be_with_and_without_bom() {
        let reference = parse_agf(ONE, "A.AGF").unwrap();
        for (be, bom) in [(false, true), (true, true), (false, false), (true, false)] {
            let bytes = utf16(&ONE.replace('\n', "\r\n"), be, bom);
            assert_eq!(
                parse_agf(&bytes, "A.AGF").unwrap(),
                reference,
                "be={be} bom={bom}"
            );
        }
        let mut odd = utf16(ONE, false, true);
        odd.push(b'x');
        assert!(matches!(
            parse_agf(&odd, "O.AGF"),
            Err(MaterialError::Encoding { .. })
        ));
    }

    #[test]
    fn latin1_comment_is_accepted() {
        let mut bytes = ONE.as_bytes().to_vec();
        bytes.extend_from_slice(b"CC caf\xe9 \xb5m\n");
        let doc = parse_agf_document(&bytes, "L.AGF").unwrap();
        assert_eq!(doc.comments[1], "café µm");
    }

    #[test]
    fn bad_number_in_cd_names_file_line_glass() {
        let text = ONE.replace("2.317923440E-01", "2.3179x3440E-01");
        let (src, line, msg) = parse_err(&text);
        assert_eq!((src.as_str(), line), ("T.AGF", 5));
        assert!(
            msg.contains("N-BK7") && msg.contains("2.3179x3440E-01") && msg.contains("CD"),
            "{msg}"
        );
        let full = parse_agf(&text, "T.AGF").unwrap_err().to_string();
        assert!(full.starts_with("T.AGF:5:"), "{full}");
    }

    #[test]
    fn record_before_nm_is_error() {
        let (_, line, msg) = parse_err("CC x\nCD 1 2 3 4 5 6\n");
        assert_eq!(line, 2);
        assert!(msg.contains("CD") && msg.contains("NM"), "{msg}");
        assert_eq!(parse_err("LD 0.3 2.5\n").1, 1);
    }

    #[test]
    fn missing_cd_or_ld_is_error_at_nm_line() {
        let (_, line, msg) = parse_err("CC\nNM A 2 0 1.5 60\nLD 0.3 2.5\n");
        assert_eq!(line, 2);
        assert!(msg.contains("A") && msg.contains("CD"), "{msg}");
        let (_, line, msg) = parse_err("NM A 2 0 1.5 60\nCD 1 0.01 0 0 0 0\nNM B 2 0 1.5 60\n");
        assert_eq!(line, 1);
        assert!(msg.contains("LD"), "{msg}");
    }

    #[test]
    fn unsupported_formula_and_too_few_coefficients() {
        let (_, line, msg) = parse_err("NM A 14 0 1.5 60\nCD 1\nLD 0.3 2.5\n");
        assert_eq!(line, 1);
        assert!(
            msg.contains("unsupported") && msg.contains("14") && msg.contains("A"),
            "{msg}"
        );
        let (_, line, msg) = parse_err("NM A 2.5 0 1.5 60\n");
        assert_eq!(line, 1);
        assert!(msg.contains("2.5"), "{msg}");
        let (_, line, msg) = parse_err("NM A 2 0 1.5 60\nCD 1 0.01 0.2\nLD 0.3 2.5\n");
        assert_eq!(line, 2);
        assert!(msg.contains("needs 6") && msg.contains("found 3"), "{msg}");
    }

    #[test]
    fn formula_number_written_as_float_is_accepted() {
        let g = parse_agf(
            "NM A 2.0 0 1.5 60\nCD 1 0.01 0 0 0 0\nLD 0.3 2.5\n",
            "F.AGF",
        )
        .unwrap();
        assert_eq!(g[0].formula.agf_number(), 2);
    }

    #[test]
    fn bad_nm_fields() {
        assert_eq!(parse_err("NM A 2 0 1.5\n").1, 1);
        let (_, _, msg) = parse_err("NM A 2 0 x1.5 60\n");
        assert!(msg.contains("nd") && msg.contains("x1.5"), "{msg}");
        let (_, _, msg) = parse_err("NM A 2 0 1.5 nan\n");
        assert!(msg.contains("vd"), "{msg}");
    }

    #[test]
    fn bad_ld() {
        let (_, line, msg) = parse_err("NM A 2 0 1.5 60\nCD 1 0.01 0 0 0 0\nLD 2.5 0.3\n");
        assert_eq!(line, 3);
        assert!(msg.contains("range"), "{msg}");
        assert_eq!(
            parse_err("NM A 2 0 1.5 60\nCD 1 0.01 0 0 0 0\nLD 0.3\n").1,
            3
        );
        assert_eq!(
            parse_err("NM A 2 0 1.5 60\nCD 1 0.01 0 0 0 0\nLD 0.3 y\n").1,
            3
        );
    }

    #[test]
    fn duplicate_names_and_records() {
        let g = "NM A 2 0 1.5 60\nCD 1 0.01 0 0 0 0\nLD 0.3 2.5\n";
        let (_, line, msg) = parse_err(&format!("{g}{}", g.replace("NM A", "NM a")));
        assert_eq!(line, 4);
        assert!(msg.contains("duplicate") && msg.contains("line 1"), "{msg}");
        let (_, line, _) = parse_err(&format!("{g}CD 1 0.01 0 0 0 0\n"));
        assert_eq!(line, 4);
    }

    #[test]
    fn lenient_records_accept_placeholders_and_empty() {
        let text = "NM A 2 0 1.5 60 0 1\nGC\nED 7.8 8.8 5.2  0\nCD 1 0.01 0 0 0 0\nTD       \n\
                    OD _ 4.0 - 52.3 2.0 3.0\nMD _ _ 360 _ _\nLD 0.3 2.5\nIT 0.3 _ 25\nBD 0.588 2.77\n";
        let g = &parse_agf(text, "P.AGF").unwrap()[0];
        assert!(g.thermal.is_none());
        assert!(g.info.transmission.is_empty());
        assert_eq!(g.info.extra.unwrap().delta_pg_f, Some(0.0));
        // Garbage (not a placeholder) in a lenient record is still an error.
        let (_, line, _) = parse_err(&text.replace("TD       ", "TD 1 2 zz"));
        assert_eq!(line, 5);
    }

    #[test]
    fn unknown_records_and_blank_lines_ignored() {
        let g = parse_agf(
            "\n\nXX whatever\nNM A 2 0 1.5 60\n\nZZ 1 2\nCD 1 0.01 0 0 0 0\nLD 0.3 2.5\n",
            "U.AGF",
        )
        .unwrap();
        assert_eq!(g.len(), 1);
    }

    /// The records of the built-in tabulated glasses (`NM name status`, `TN λ n`; `builtin_catalogs`) mean
    /// nothing in a user's AGF: `TN` is an unknown record, ignored as before, and a glass with points but no
    /// `CD`/`LD` is refused as before — no tabulated glass comes from a user's file.
    #[test]
    fn tabulated_records_are_unknown_in_a_users_agf() {
        let g = parse_agf("NM A 2 0 1.5 60\nCD 1 0.01 0 0 0 0\nLD 0.3 2.5\nTN 0.5 1.6\nTN 0.6 1.7\n", "U.AGF").unwrap();
        assert_eq!((g.len(), g[0].formula.agf_number()), (1, 2));
        assert_eq!(g[0].refractive_index(500.0).unwrap(), g[0].formula.refractive_index(500.0));
        let e = parse_agf("NM B270 0 0 1.523 58.5\nTN 0.5 1.6\nTN 0.6 1.7\n", "U.AGF").unwrap_err().to_string();
        assert!(e.starts_with("U.AGF:1:") && e.contains("B270") && e.contains("formula number 0"), "{e}");
        let e = parse_agf("NM B270 2 0 1.523 58.5\nTN 0.5 1.6\nTN 0.6 1.7\n", "U.AGF").unwrap_err().to_string();
        assert!(e.starts_with("U.AGF:1:") && e.contains("B270") && e.contains("CD"), "{e}");
    }

    #[test]
    fn catalog_names() {
        assert_eq!(catalog_name_from_source("/a/b/ohara.agf"), "OHARA");
        assert_eq!(catalog_name_from_source("SCHOTT.AGF"), "SCHOTT");
    }
}
