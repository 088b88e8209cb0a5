//! A tiny CSV reader and writer for numeric tables (Zemax exports, ray lists, results).
//!
//! # Reading
//!
//! [`read_columns`] picks columns by header name and returns them as `f64` vectors:
//!
//! * blank lines and lines whose first non-blank character is `#` are skipped, anywhere;
//! * the first remaining line is the header; the remaining lines are data rows;
//! * fields are separated by `,`; surrounding spaces/tabs are trimmed; a field may be enclosed in
//!   double quotes (`"a, b"`, with `""` for a literal quote) but may not span lines;
//! * `\r\n` line ends and a leading UTF-8 byte-order mark are accepted;
//! * columns that are not requested are ignored (they may hold text); requested columns may come in
//!   any order and each must appear exactly once in the header;
//! * values are parsed with Rust's `f64::from_str`, so `1.5`, `-2e-3`, `inf`, `-inf` and `NaN`
//!   (case-insensitive) are accepted; a missing/empty value or anything else is an error naming
//!   the file, the line, the column and the offending text. A missing column lists the available
//!   ones.
//!
//! # Writing
//!
//! [`CsvWriter`] buffers a header and rows in memory and writes the file atomically in
//! [`CsvWriter::finish`]. Numbers are written in the **shortest representation that round-trips
//! exactly** (Rust's `{}` for `1e-4 <= |x| < 1e15` and zero, `{:e}` otherwise, e.g. `0.1`, `-2.5`,
//! `1.2345e-7`, `6.02214076e23`), so reading the file back gives bit-identical values; non-finite
//! values are written as `NaN`, `inf`, `-inf`. Strings are quoted only when needed.
//!
//! # Example
//!
//! ```
//! use diffcassi::io::{read_columns, CsvValue, CsvWriter};
//!
//! # fn main() -> Result<(), diffcassi::io::IoError> {
//! let path = std::env::temp_dir().join(format!("diffcassi_csv_doc_{}.csv", std::process::id()));
//! let mut w = CsvWriter::new(&path, &["field", "px", "py"])?;
//! w.comment("wavelength_um: 0.45"); // before the first row: written above the header
//! w.row(&[CsvValue::from("F1"), 0.1.into(), (-0.25).into()])?;
//! w.row(&["F2".into(), 1e-9.into(), 3.0.into()])?;
//! w.finish()?;
//! assert_eq!(
//!     std::fs::read_to_string(&path).unwrap(),
//!     "# wavelength_um: 0.45\nfield,px,py\nF1,0.1,-0.25\nF2,1e-9,3\n"
//! );
//!
//! let cols = read_columns(&path, &["py", "px"])?;
//! assert_eq!(cols, vec![vec![-0.25, 3.0], vec![0.1, 1e-9]]);
//!
//! let err = read_columns(&path, &["x_mm"]).unwrap_err();
//! assert!(err.to_string().contains("no column named 'x_mm'"));
//! assert!(err.to_string().contains("available columns: field, px, py"));
//! # std::fs::remove_file(&path).ok();
//! # Ok(())
//! # }
//! ```

use std::borrow::Cow;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::{write_atomic, IoError};

/// Read the named numeric columns of a CSV file; `result[k]` holds the values of `names[k]`, one
/// per data row. See the [module documentation](self) for the accepted syntax.
pub fn read_columns(path: impl AsRef<Path>, names: &[&str]) -> Result<Vec<Vec<f64>>, IoError> {
    let path = path.as_ref();
    let text = super::input::read_input_text(path, crate::limits::MAX_TEXT_FILE_BYTES)?;
    parse_columns(path, &text, names)
}

/// Same as [`read_columns`] for text already in memory; `path` is only used in error messages.
pub fn parse_columns(path: &Path, text: &str, names: &[&str]) -> Result<Vec<Vec<f64>>, IoError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    // Line ends: LF, CRLF, or a lone CR (classic Mac OS; its lines were read as one, `py\r0`).
    let mut lines = text
        .split('\n')
        .flat_map(|l| l.strip_suffix('\r').unwrap_or(l).split('\r'))
        .enumerate()
        .map(|(i, l)| (i + 1, l))
        .filter(|(_, l)| {
            let t = l.trim_start();
            !t.is_empty() && !t.starts_with('#')
        });

    let (header_line, header) = lines.next().ok_or_else(|| IoError::CsvNoHeader {
        path: path.to_path_buf(),
    })?;
    let header = split_fields(header).map_err(|reason| IoError::CsvSyntax {
        path: path.to_path_buf(),
        line: header_line,
        reason,
    })?;

    let mut index = Vec::with_capacity(names.len());
    for &name in names {
        let mut hits = header
            .iter()
            .enumerate()
            .filter(|(_, h)| h.as_ref() == name)
            .map(|(i, _)| i);
        let first = hits.next().ok_or_else(|| IoError::CsvMissingColumn {
            path: path.to_path_buf(),
            line: header_line,
            column: name.to_string(),
            // Control characters escaped (a NUL in `px\0` printed as an invisible `px`, "missing" beside "available").
            available: header.iter().map(|h| h.chars().map(|c| if c.is_control() { c.escape_default().to_string() } else { c.to_string() }).collect()).collect(),
        })?;
        if let Some(second) = hits.next() {
            return Err(IoError::CsvDuplicateColumn {
                path: path.to_path_buf(),
                line: header_line,
                column: name.to_string(),
                first: first + 1,
                second: second + 1,
            });
        }
        index.push(first);
    }

    let mut columns: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
    for (line, content) in lines {
        let fields = split_fields(content).map_err(|reason| IoError::CsvSyntax {
            path: path.to_path_buf(),
            line,
            reason,
        })?;
        for (k, &i) in index.iter().enumerate() {
            let value = match fields.get(i) {
                Some(v) if !v.is_empty() => v,
                _ => {
                    return Err(IoError::CsvMissingValue {
                        path: path.to_path_buf(),
                        line,
                        column: names[k].to_string(),
                        field: i + 1,
                        fields_in_row: fields.len(),
                    })
                }
            };
            let x: f64 = value.parse().map_err(|_| IoError::CsvParse {
                path: path.to_path_buf(),
                line,
                column: names[k].to_string(),
                field: i + 1,
                value: value.to_string(),
            })?;
            columns[k].push(x);
        }
    }
    Ok(columns)
}

/// Split one line into trimmed fields, honouring double quotes.
fn split_fields(line: &str) -> Result<Vec<Cow<'_, str>>, String> {
    let mut fields = Vec::new();
    let mut rest = line;
    loop {
        let trimmed = rest.trim_start_matches([' ', '\t']);
        if let Some(inner) = trimmed.strip_prefix('"') {
            // Quoted field: read up to the closing quote, "" is an escaped quote.
            let mut value = String::new();
            let mut chars = inner.char_indices();
            let end = loop {
                match chars.next() {
                    Some((i, '"')) => {
                        if inner[i + 1..].starts_with('"') {
                            value.push('"');
                            chars.next();
                        } else {
                            break i + 1;
                        }
                    }
                    Some((_, c)) => value.push(c),
                    None => {
                        return Err(format!(
                            "unterminated quoted field (field {})",
                            fields.len() + 1
                        ))
                    }
                }
            };
            let after = inner[end..].trim_start_matches([' ', '\t']);
            fields.push(Cow::Owned(value));
            match after.strip_prefix(',') {
                Some(r) => rest = r,
                None if after.is_empty() => return Ok(fields),
                None => {
                    return Err(format!(
                        "unexpected text after the closing quote of field {}",
                        fields.len()
                    ))
                }
            }
        } else {
            match trimmed.find(',') {
                Some(i) => {
                    fields.push(Cow::Borrowed(trimmed[..i].trim_end_matches([' ', '\t'])));
                    rest = &trimmed[i + 1..];
                }
                None => {
                    fields.push(Cow::Borrowed(trimmed.trim_end_matches([' ', '\t'])));
                    return Ok(fields);
                }
            }
        }
    }
}

/// One cell for [`CsvWriter::row`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CsvValue<'a> {
    /// Written in shortest round-trip form (see the module documentation).
    F64(f64),
    /// Written in decimal.
    Int(i64),
    /// Written verbatim, or quoted when it is empty, contains `,` or `"`, has surrounding
    /// whitespace, or starts with `#`. Line breaks are rejected.
    Str(&'a str),
}

impl From<f64> for CsvValue<'_> {
    fn from(v: f64) -> Self {
        CsvValue::F64(v)
    }
}
impl From<f32> for CsvValue<'_> {
    fn from(v: f32) -> Self {
        CsvValue::F64(v as f64)
    }
}
impl From<i64> for CsvValue<'_> {
    fn from(v: i64) -> Self {
        CsvValue::Int(v)
    }
}
impl From<i32> for CsvValue<'_> {
    fn from(v: i32) -> Self {
        CsvValue::Int(v as i64)
    }
}
impl From<u32> for CsvValue<'_> {
    fn from(v: u32) -> Self {
        CsvValue::Int(v as i64)
    }
}
impl From<usize> for CsvValue<'_> {
    fn from(v: usize) -> Self {
        // Saturates above i64::MAX (9.2e18), which no table index reaches.
        CsvValue::Int(i64::try_from(v).unwrap_or(i64::MAX))
    }
}
impl<'a> From<&'a str> for CsvValue<'a> {
    fn from(v: &'a str) -> Self {
        CsvValue::Str(v)
    }
}
impl<'a> From<&'a String> for CsvValue<'a> {
    fn from(v: &'a String) -> Self {
        CsvValue::Str(v)
    }
}

/// Shortest text that parses back to exactly `x` (see the module documentation).
pub(crate) fn format_f64(x: f64) -> String {
    if x.is_nan() {
        "NaN".to_string()
    } else if x.is_infinite() {
        if x > 0.0 { "inf" } else { "-inf" }.to_string()
    } else if x == 0.0 || (1e-4..1e15).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// Builds a CSV file in memory and writes it atomically with [`finish`](Self::finish).
///
/// Dropping a writer without calling `finish` writes nothing.
#[derive(Debug)]
#[must_use = "nothing is written until CsvWriter::finish is called"]
pub struct CsvWriter {
    path: PathBuf,
    header: String,
    columns: usize,
    /// Comment lines given before the first row (written above the header).
    preamble: String,
    body: String,
    rows: usize,
}

impl CsvWriter {
    /// Start a table with the given column names (non-empty, distinct, no line breaks).
    pub fn new(path: impl AsRef<Path>, header: &[&str]) -> Result<Self, IoError> {
        let path = path.as_ref().to_path_buf();
        let bad = |reason: String| IoError::CsvValue {
            path: path.clone(),
            row: 0,
            reason,
        };
        if header.is_empty() {
            return Err(bad("the header has no columns".to_string()));
        }
        for (i, name) in header.iter().enumerate() {
            if name.trim().is_empty() {
                return Err(bad(format!("header column {} has an empty name", i + 1)));
            }
            if let Some(j) = header[..i].iter().position(|n| n == name) {
                return Err(bad(format!(
                    "header column '{name}' appears twice (columns {} and {})",
                    j + 1,
                    i + 1
                )));
            }
        }
        let mut line = String::new();
        for (i, name) in header.iter().enumerate() {
            if i > 0 {
                line.push(',');
            }
            push_str_field(&mut line, name)
                .map_err(|r| bad(format!("header column {}: {r}", i + 1)))?;
        }
        line.push('\n');
        Ok(CsvWriter {
            path,
            header: line,
            columns: header.len(),
            preamble: String::new(),
            body: String::new(),
            rows: 0,
        })
    }

    /// Add `# text` comment line(s) (one per line of `text`). Comments added before the first row
    /// are placed above the header.
    pub fn comment(&mut self, text: &str) {
        let target = if self.rows == 0 {
            &mut self.preamble
        } else {
            &mut self.body
        };
        // Long numbers in exponent form (a field of 5e-324 mm is not 324 digits), as in error messages.
        for line in crate::error::tidy_numbers(text).lines() {
            let _ = writeln!(target, "# {line}");
        }
        if text.is_empty() {
            target.push_str("#\n");
        }
    }

    /// Append a row of mixed values; it must have one value per header column.
    pub fn row(&mut self, values: &[CsvValue<'_>]) -> Result<(), IoError> {
        self.check_len(values.len())?;
        let start = self.body.len();
        for (i, v) in values.iter().enumerate() {
            if i > 0 {
                self.body.push(',');
            }
            match *v {
                CsvValue::F64(x) => self.body.push_str(&format_f64(x)),
                CsvValue::Int(n) => {
                    let _ = write!(self.body, "{n}");
                }
                CsvValue::Str(s) => {
                    if let Err(reason) = push_str_field(&mut self.body, s) {
                        self.body.truncate(start);
                        return Err(IoError::CsvValue {
                            path: self.path.clone(),
                            row: self.rows + 1,
                            reason: format!("field {}: {reason}", i + 1),
                        });
                    }
                }
            }
        }
        self.body.push('\n');
        self.rows += 1;
        Ok(())
    }

    /// Append a row of numbers; it must have one value per header column.
    pub fn row_f64(&mut self, values: &[f64]) -> Result<(), IoError> {
        self.check_len(values.len())?;
        for (i, &x) in values.iter().enumerate() {
            if i > 0 {
                self.body.push(',');
            }
            self.body.push_str(&format_f64(x));
        }
        self.body.push('\n');
        self.rows += 1;
        Ok(())
    }

    /// Number of data rows added so far.
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// The destination path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The complete file content as it would be written now.
    pub fn contents(&self) -> String {
        let mut s =
            String::with_capacity(self.preamble.len() + self.header.len() + self.body.len());
        s.push_str(&self.preamble);
        s.push_str(&self.header);
        s.push_str(&self.body);
        s
    }

    /// Write the file atomically (creating parent directories).
    pub fn finish(self) -> Result<(), IoError> {
        write_atomic(&self.path, self.contents().as_bytes())
    }

    fn check_len(&self, n: usize) -> Result<(), IoError> {
        if n == self.columns {
            Ok(())
        } else {
            Err(IoError::CsvRowLength {
                path: self.path.clone(),
                row: self.rows + 1,
                expected: self.columns,
                actual: n,
            })
        }
    }
}

fn push_str_field(out: &mut String, s: &str) -> Result<(), String> {
    if s.contains(['\n', '\r']) {
        return Err(format!("text {s:?} contains a line break"));
    }
    let needs_quotes = s.is_empty()
        || s.contains([',', '"'])
        || s.starts_with('#')
        || s.starts_with([' ', '\t'])
        || s.ends_with([' ', '\t']);
    if needs_quotes {
        out.push('"');
        out.push_str(&s.replace('"', "\"\""));
        out.push('"');
    } else {
        out.push_str(s);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn parse(text: &str, names: &[&str]) -> Result<Vec<Vec<f64>>, IoError> {
        parse_columns(Path::new("in.csv"), text, names)
    }

    #[test]
    fn reads_zemax_style_file() {
        let text = "# source: x.txt\n# x_chief_mm: -3.0025\n\npx,py,x_mm,y_mm\r\n\
                    -0.9750,-0.2000,-2.9871,0.0008\r\n\n# interleaved comment\n  \
                    0.9750 , 0.2000,-3.0121,1e-4\n";
        let cols = parse(text, &["y_mm", "px"]).unwrap();
        assert_eq!(cols, vec![vec![0.0008, 1e-4], vec![-0.975, 0.975]]);
        assert_eq!(parse(text, &[]).unwrap(), Vec::<Vec<f64>>::new());
    }

    #[test]
    fn ignores_unrequested_text_columns_and_quotes() {
        let text = "\u{feff}name,\"x, mm\",note\n\"a,b\",1.5,\"say \"\"hi\"\"\"\nc, \"-2\" ,\n";
        assert_eq!(parse(text, &["x, mm"]).unwrap(), vec![vec![1.5, -2.0]]);
        assert_eq!(
            parse("a\ninf\n-INF\nNaN\n", &["a"]).unwrap()[0][..2],
            [f64::INFINITY, f64::NEG_INFINITY]
        );
    }

    #[test]
    fn header_only_gives_empty_columns() {
        assert_eq!(parse("a,b\n", &["b"]).unwrap(), vec![Vec::<f64>::new()]);
    }

    #[test]
    fn error_messages() {
        let msg = |t: &str, n: &[&str]| parse(t, n).unwrap_err().to_string();
        assert_eq!(
            msg("# c\npx,py\n1,2\n3,abc\n", &["px", "py"]),
            "in.csv:4: column 'py' (field 2): cannot parse 'abc' as a number"
        );
        assert_eq!(
            msg("px,py\n1\n", &["py"]),
            "in.csv:2: missing value for column 'py' (field 2; the row has 1 fields)"
        );
        assert_eq!(
            msg("px,py\n1,  \n", &["py"]),
            "in.csv:2: missing value for column 'py' (field 2; the row has 2 fields)"
        );
        assert_eq!(
            msg("\n# only\npx,py,x_mm\n", &["px", "y_mm"]),
            "in.csv:3: no column named 'y_mm' in the header; available columns: px, py, x_mm"
        );
        assert_eq!(
            msg("a,b,a\n", &["a"]),
            "in.csv:1: column 'a' appears more than once in the header (fields 1 and 3)"
        );
        assert!(msg("# nothing\n\n", &["a"]).contains("no header line"));
        assert!(msg("", &["a"]).contains("no header line"));
        assert!(msg("a\n\"1\n", &["a"]).starts_with("in.csv:2: unterminated quoted field"));
        assert!(msg("a\n\"1\"x\n", &["a"]).contains("unexpected text after the closing quote"));
    }

    #[test]
    fn missing_file_names_path() {
        let e = read_columns("/nonexistent/dir/f.csv", &["a"]).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("/nonexistent/dir/f.csv: cannot read"),
            "{e}"
        );
    }

    #[test]
    fn number_format() {
        for (x, s) in [
            (0.0, "0"),
            (-0.0, "-0"),
            (1.0, "1"),
            (0.1, "0.1"),
            (-2.5, "-2.5"),
            (1e-4, "0.0001"),
            (9.9e-5, "9.9e-5"),
            (123456.789, "123456.789"),
            (1e15, "1e15"),
            (f64::MAX, "1.7976931348623157e308"),
            (5e-324, "5e-324"),
            (f64::NAN, "NaN"),
            (f64::INFINITY, "inf"),
            (f64::NEG_INFINITY, "-inf"),
        ] {
            assert_eq!(format_f64(x), s);
        }
    }

    #[test]
    fn writer_round_trip_and_layout() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("sub/out.csv");
        let mut w = CsvWriter::new(&p, &["label", "x", "n"]).unwrap();
        w.comment("first\nsecond");
        w.row(&["#hash".into(), 0.1.into(), 3usize.into()]).unwrap();
        w.comment("between");
        w.row(&[" padded".into(), f64::NAN.into(), (-7i64).into()])
            .unwrap();
        w.row(&["q\"uote, comma".into(), 1e300.into(), 0i32.into()])
            .unwrap();
        assert_eq!(w.rows(), 3);
        w.finish().unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        assert_eq!(
            text,
            "# first\n# second\nlabel,x,n\n\"#hash\",0.1,3\n# between\n\" padded\",NaN,-7\n\
             \"q\"\"uote, comma\",1e300,0\n"
        );
        let cols = read_columns(&p, &["n", "x"]).unwrap();
        assert_eq!(cols[0], vec![3.0, -7.0, 0.0]);
        assert_eq!(cols[1][0], 0.1);
        assert!(cols[1][1].is_nan());
        assert_eq!(cols[1][2], 1e300);
    }

    #[test]
    fn writer_errors() {
        let p = Path::new("/tmp/w.csv");
        assert!(CsvWriter::new(p, &[]).is_err());
        assert!(CsvWriter::new(p, &["a", " "]).is_err());
        let e = CsvWriter::new(p, &["a", "b", "a"]).unwrap_err().to_string();
        assert!(
            e.contains("/tmp/w.csv") && e.contains("appears twice"),
            "{e}"
        );
        let mut w = CsvWriter::new(p, &["a", "b"]).unwrap();
        let e = w.row_f64(&[1.0]).unwrap_err().to_string();
        assert_eq!(
            e,
            "/tmp/w.csv: row 1 has 1 fields but the header has 2 columns"
        );
        let e = w.row(&["x\ny".into(), 1.0.into()]).unwrap_err().to_string();
        assert!(
            e.contains("row 1: field 1") && e.contains("line break"),
            "{e}"
        );
        w.row_f64(&[1.0, 2.0]).unwrap();
        assert_eq!(w.contents(), "a,b\n1,2\n");
    }

    proptest! {
        #[test]
        fn prop_f64_round_trip(bits in any::<u64>(), y in any::<f64>()) {
            let x = f64::from_bits(bits);
            let tmp = tempfile::tempdir().unwrap();
            let p = tmp.path().join("r.csv");
            let mut w = CsvWriter::new(&p, &["x", "y"]).unwrap();
            w.row_f64(&[x, y]).unwrap();
            w.finish().unwrap();
            let c = read_columns(&p, &["x", "y"]).unwrap();
            if x.is_nan() { prop_assert!(c[0][0].is_nan()); } else { prop_assert_eq!(c[0][0].to_bits(), x.to_bits()); }
            if y.is_nan() { prop_assert!(c[1][0].is_nan()); } else { prop_assert_eq!(c[1][0].to_bits(), y.to_bits()); }
        }

        #[test]
        fn prop_string_fields_round_trip(s in "[ -~]{0,12}") {
            // Any printable ASCII text survives the writer's quoting and the reader's splitting
            // (the reader trims unquoted fields, and the writer quotes padded ones).
            let mut w = CsvWriter::new("/tmp/unused.csv", &["s", "v"]).unwrap();
            w.row(&[CsvValue::Str(&s), 1.0.into()]).unwrap();
            let text = w.contents();
            let line = text.lines().nth(1).unwrap();
            let fields = split_fields(line).unwrap();
            prop_assert_eq!(fields.len(), 2);
            prop_assert_eq!(fields[0].as_ref(), s.as_str());
        }
    }
}
