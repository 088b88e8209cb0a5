//! Decoding and tokenising a `.zmx` file: the encodings OpticStudio writes and one record per line.
//!
//! OpticStudio writes `.zmx` as UTF-16 LE with a byte-order mark (current versions), as ANSI text in the
//! Windows code page (older versions: Windows-1252 in western locales) or as ASCII; other tools write UTF-8.
//! [`decode`] reads, in this order: UTF-16 LE or BE with a byte-order mark; UTF-8 with or without its BOM
//! (`EF BB BF`); and any other text, whose bytes are not valid UTF-8, as Windows-1252 (so `°`, `µ`, `é` of
//! an ANSI `NOTE` or `COMM` come out as written; [`TextEncoding`] says which one was used). A record is a
//! line, ended by CRLF, LF or a CR alone (all three, in any mix, in every encoding): a keyword (`SURF`, `CURV`, `GLAS`…) followed by whitespace-separated arguments; an argument in
//! double quotes may hold spaces. Refused, with a message naming the problem: UTF-16 without a byte-order
//! mark (the NUL bytes of every other byte give it away), a binary file (a NUL byte anywhere, or control
//! characters other than tab, CR, LF and form feed — in Windows-1252 also the five undefined bytes
//! 0x81, 0x8D, 0x8F, 0x90, 0x9D), a file with no record at all.
//!
//! ```
//! use diffcassi::spec::zmx::lexer::{decode, records};
//! let mut bytes = vec![0xFF, 0xFE];
//! for u in "SURF 0\r\n  DISZ 5\r\n".encode_utf16() { bytes.extend(u.to_le_bytes()); }
//! let text = decode(&bytes, "a.zmx").unwrap();
//! let recs = records(&text);
//! assert_eq!(recs[1].keyword, "DISZ");
//! assert_eq!(recs[1].args, vec!["5".to_string()]);
//! assert_eq!(recs[1].line, 2);
//! ```
use crate::error::{Error, Result};

/// One line of a `.zmx` file.
#[derive(Clone, Debug, PartialEq)]
pub struct Record {
    /// 1-based line number in the file.
    pub line: usize,
    /// The keyword (upper case as written, e.g. `CURV`).
    pub keyword: String,
    /// The arguments, quotes removed.
    pub args: Vec<String>,
    /// The text after the keyword, verbatim (for `NAME`, `NOTE`, `COMM`).
    pub rest: String,
    /// The line starts with whitespace (OpticStudio indents the records of a surface, not the others).
    pub indented: bool,
}

/// The text encoding a `.zmx` file was read in (see [`decode_with_encoding`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TextEncoding {
    Utf16Le,
    Utf16Be,
    /// UTF-8 with its byte-order mark.
    Utf8Bom,
    /// UTF-8 without a byte-order mark (ASCII included).
    Utf8,
    /// Not valid UTF-8, no byte-order mark: ANSI text read as Windows-1252.
    Windows1252,
}

impl TextEncoding {
    /// How `info` names it.
    pub fn label(self) -> &'static str {
        match self {
            Self::Utf16Le => "UTF-16 LE with byte-order mark",
            Self::Utf16Be => "UTF-16 BE with byte-order mark",
            Self::Utf8Bom => "UTF-8 with byte-order mark",
            Self::Utf8 => "UTF-8 / ASCII",
            Self::Windows1252 => "ANSI (Windows-1252)",
        }
    }
}

/// Decode the bytes of a `.zmx` file (UTF-16 LE/BE with BOM, UTF-8 with or without BOM, Windows-1252).
pub fn decode(bytes: &[u8], source_name: &str) -> Result<String> {
    decode_with_encoding(bytes, source_name).map(|d| d.0)
}

/// [`decode`], also saying which encoding was read.
pub fn decode_with_encoding(bytes: &[u8], source_name: &str) -> Result<(String, TextEncoding)> {
    let fail = |m: String| Error::spec(source_name, m);
    if bytes.is_empty() {
        return Err(fail("empty file: not a Zemax .zmx lens file".into()));
    }
    let utf16 = |be: bool, body: &[u8]| -> Result<String> {
        if body.len() % 2 != 0 {
            return Err(fail(format!("UTF-16 file with an odd number of bytes ({}): truncated", body.len() + 2)));
        }
        let units: Vec<u16> =
            body.chunks_exact(2).map(|c| if be { u16::from_be_bytes([c[0], c[1]]) } else { u16::from_le_bytes([c[0], c[1]]) }).collect();
        let text = String::from_utf16(&units).map_err(|_| fail("invalid UTF-16 (an unpaired surrogate): not a Zemax .zmx text file".into()))?;
        let text = unify_line_ends(text);
        check_text(&text, source_name)?;
        Ok(text)
    };
    if let Some(body) = bytes.strip_prefix(&[0xFF, 0xFE]) {
        return Ok((utf16(false, body)?, TextEncoding::Utf16Le));
    }
    if let Some(body) = bytes.strip_prefix(&[0xFE, 0xFF]) {
        return Ok((utf16(true, body)?, TextEncoding::Utf16Be));
    }
    let (body, bom) = match bytes.strip_prefix(&[0xEF, 0xBB, 0xBF]) {
        Some(b) => (b, true),
        None => (bytes, false),
    };
    let head = &body[..body.len().min(512)];
    let nul_odd = head.iter().skip(1).step_by(2).filter(|b| **b == 0).count();
    let nul_even = head.iter().step_by(2).filter(|b| **b == 0).count();
    if head.len() >= 8 && (nul_odd * 4 >= head.len() / 2 || nul_even * 4 >= head.len() / 2) && nul_odd.min(nul_even) == 0 {
        return Err(fail(
            "UTF-16 text without a byte-order mark (every other byte is NUL): OpticStudio writes UTF-16 with a BOM (FF FE); re-save the file from OpticStudio or convert it to UTF-8".into(),
        ));
    }
    if let Some(pos) = body.iter().position(|b| *b == 0) {
        return Err(fail(format!("binary file (a NUL byte at offset {pos}): not a Zemax .zmx text file (a .zos or .zmx archive is binary)")));
    }
    let (text, enc) = match std::str::from_utf8(body) {
        Ok(t) => (t.to_string(), if bom { TextEncoding::Utf8Bom } else { TextEncoding::Utf8 }),
        Err(e) if bom => {
            return Err(fail(format!("a UTF-8 byte-order mark but invalid UTF-8 at offset {}: not a Zemax .zmx text file", e.valid_up_to() + 3)))
        }
        // ANSI text: every byte is a character of Windows-1252 (encoding_rs maps its five undefined bytes to
        // C1 controls, which check_text refuses as binary).
        Err(_) => (decode_windows_1252(body), TextEncoding::Windows1252),
    };
    let text = unify_line_ends(text);
    check_text(&text, source_name)?;
    Ok((text, enc))
}

/// ANSI text (bytes that are not valid UTF-8, no byte-order mark) as Windows-1252, OpticStudio's code page in
/// western locales: the one 8-bit rule of every Zemax text file diffcassi reads, `.zmx` and AGF catalogues
/// alike ([`crate::materials::decode_agf_bytes`]), so that a glass name with a byte in 0x80–0x9F (`™` 0x99,
/// `€` 0x80) reads the same in a lens file and in its catalogue (the AGF reader used Latin-1, where those bytes
/// are C1 controls: `GLAS G™X` was "in none of the loaded catalogues" though its catalogue held it; round 19).
/// The five bytes Windows-1252 leaves undefined (0x81, 0x8D, 0x8F, 0x90, 0x9D) come out as C1 controls, which
/// both readers refuse as binary.
pub fn decode_windows_1252(bytes: &[u8]) -> String {
    encoding_rs::WINDOWS_1252.decode_without_bom_handling(bytes).0.into_owned()
}

/// Every line end as LF: CRLF (OpticStudio), LF, and a CR alone (classic Mac OS; a stray one in a file of
/// other line ends) each end a line, in every encoding, as Python's universal newlines read them (optiland,
/// rayoptics). A lone CR read as whitespace joined two records into one line (`CURV 0.02 0 0 0 0 "" DISZ 5`:
/// the thickness lost), and a UTF-16 file with CR line ends read as one line ("no `SURF` record"). The one line
/// splitter of the Zemax text readers: the AGF reader uses it too ([`crate::materials::decode_agf_bytes`]; with
/// `str::lines`, which ends a line at LF only, a glass after a CR-ended `LD` or `GC` record was swallowed and
/// the built-in glass of its name used instead; round 19).
pub fn unify_line_ends(text: String) -> String {
    if text.contains('\r') {
        text.replace("\r\n", "\n").replace('\r', "\n")
    } else {
        text
    }
}

/// Control characters other than tab, CR, LF and form feed mark a binary file (CR is gone by then: every line end is LF).
fn check_text(text: &str, source_name: &str) -> Result<()> {
    for (i, line) in text.lines().enumerate() {
        if let Some(c) = line.chars().find(|c| c.is_control() && !matches!(c, '\t' | '\r' | '\x0c')) {
            return Err(Error::spec(
                source_name,
                format!("line {}: control character U+{:04X}: a binary file, not a Zemax .zmx text file", i + 1, c as u32),
            ));
        }
    }
    Ok(())
}

/// Split decoded text into records (blank lines skipped).
pub fn records(text: &str) -> Vec<Record> {
    let mut out = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.is_empty() {
            continue;
        }
        let (keyword, rest) = match line.find(char::is_whitespace) {
            Some(k) => (&line[..k], line[k..].trim()),
            None => (line, ""),
        };
        let indented = raw.starts_with(char::is_whitespace);
        out.push(Record { line: i + 1, keyword: keyword.to_string(), args: split_args(rest), rest: rest.to_string(), indented });
    }
    out
}

/// Whitespace-separated arguments; `"a b"` is one argument (quotes removed).
fn split_args(rest: &str) -> Vec<String> {
    let mut args = Vec::new();
    let mut cur = String::new();
    let (mut quoted, mut any) = (false, false);
    for c in rest.chars() {
        match c {
            '"' => {
                quoted = !quoted;
                any = true;
            }
            c if c.is_whitespace() && !quoted => {
                if any {
                    args.push(std::mem::take(&mut cur));
                    any = false;
                }
            }
            c => {
                cur.push(c);
                any = true;
            }
        }
    }
    if any {
        args.push(cur);
    }
    args
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encodings() {
        let text = "VERS 1\nSURF 0\n";
        assert_eq!(decode(text.as_bytes(), "a").unwrap(), text);
        let mut le = vec![0xFF, 0xFE];
        let mut be = vec![0xFE, 0xFF];
        for u in text.encode_utf16() {
            le.extend(u.to_le_bytes());
            be.extend(u.to_be_bytes());
        }
        assert_eq!(decode(&le, "a").unwrap(), text);
        assert_eq!(decode(&be, "a").unwrap(), text);
        let no_bom: Vec<u8> = le[2..].to_vec();
        assert!(decode(&no_bom, "a").unwrap_err().to_string().contains("without a byte-order mark"));
        assert!(decode(&[1, 2, 0, 3, 200, 201, 7, 9, 0, 0, 4], "a").unwrap_err().to_string().contains("binary"));
        assert!(decode(b"", "a").is_err());
        // UTF-8 with BOM; ANSI (Windows-1252): 0xB0 °, 0xB5 µ, 0xE9 é, 0x80 €.
        let (t, e) = decode_with_encoding(b"\xEF\xBB\xBFNOTE 0 \xC2\xB5m\n", "a").unwrap();
        assert_eq!((t.as_str(), e), ("NOTE 0 µm\n", TextEncoding::Utf8Bom));
        let (t, e) = decode_with_encoding(b"NOTE 0 20\xB0 \xB5m caf\xE9 \x80\r\n", "a").unwrap();
        assert_eq!((t.as_str(), e), ("NOTE 0 20° µm café €\n", TextEncoding::Windows1252));
        // A UTF-8 BOM before invalid UTF-8, an undefined Windows-1252 byte, control bytes: refused.
        assert!(decode(b"\xEF\xBB\xBFNOTE \xB5\n", "a").unwrap_err().to_string().contains("invalid UTF-8"));
        assert!(decode(b"NOTE \x81 \xB5\n", "a").unwrap_err().to_string().contains("binary"));
        assert!(decode(b"NOTE \x01\xB5\n", "a").unwrap_err().to_string().contains("binary"));
    }

    #[test]
    fn quoted_arguments() {
        let r = records("  DIAM 7.5 1 0 0 1 \"\"\nCOMM a \"b c\"\n");
        assert_eq!(r[0].args, vec!["7.5", "1", "0", "0", "1", ""]);
        assert_eq!(r[1].args, vec!["a", "b c"]);
        assert_eq!(r[1].rest, "a \"b c\"");
    }
}
