//! NumPy `.npy` files (format version 1.0): little-endian, C (row-major) order, any shape.
//!
//! Writers: [`write_npy_f64`] (`'<f8'`), [`write_npy_f32`] (`'<f4'`), [`write_npy_u8`] (`'|u1'`),
//! [`write_npy_u16`] (`'<u2'`), or the generic [`write_npy`]. The shape must hold exactly as many
//! elements as given (`shape.iter().product() == data.len()`, an empty shape `[]` is a 0-d scalar
//! holding one element), otherwise [`IoError::ShapeMismatch`] is returned. Files are written
//! atomically (see [`super::write_atomic_with`]).
//!
//! The header follows the specification exactly: the magic string `\x93NUMPY`, version `1.0`, a
//! little-endian `u16` header length, then the Python dict literal, e.g.
//! `{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }`, padded with spaces and
//! terminated by `\n` so that the data starts at a multiple of 64 bytes (the padding rule is the
//! one `numpy.lib.format` uses). Format 2.0 (`u32` header length) is used only if the header would
//! not fit in 65535 bytes, as NumPy does.
//!
//! Reader: [`read_npy_f64`] returns `(shape, data)` and accepts little-endian `'<f8'` and `'<f4'`
//! (and the integer types written here, `'|u1'` and `'<u2'`), all converted to `f64`, in C order,
//! from format versions 1.0, 2.0 and 3.0. Fortran-order arrays, big-endian data, other dtypes,
//! truncated files and trailing bytes after the data are reported as [`IoError::Npy`].
//!
//! # Example
//!
//! ```
//! use diffcassi::io::{read_npy_f64, write_npy_f32};
//!
//! # fn main() -> Result<(), diffcassi::io::IoError> {
//! let path = std::env::temp_dir().join(format!("diffcassi_npy_doc_{}.npy", std::process::id()));
//! // A 2 x 2 x 3 cube, C order: the last index varies fastest.
//! let cube: Vec<f32> = (0..12).map(|i| i as f32 * 0.5).collect();
//! write_npy_f32(&path, &[2, 2, 3], &cube)?;
//! let (shape, data) = read_npy_f64(&path)?; // f32 values are widened to f64
//! assert_eq!(shape, vec![2, 2, 3]);
//! assert_eq!(data[11], 5.5);
//! // A wrong shape is an error, not a panic:
//! assert!(write_npy_f32(&path, &[5, 5], &cube).is_err());
//! # std::fs::remove_file(&path).ok();
//! # Ok(())
//! # }
//! ```

use std::io::Write;
use std::path::Path;

use super::{write_atomic_with, IoError};

const MAGIC: &[u8; 6] = b"\x93NUMPY";
const ALIGN: usize = 64;

mod sealed {
    pub trait Sealed {}
}

/// Element types that can be written to `.npy` files.
pub trait NpyElement: Copy + sealed::Sealed {
    /// The NumPy dtype string, e.g. `'<f8'` is `"<f8"`.
    const DESCR: &'static str;
    /// Append the little-endian bytes of `values` to `out`.
    fn extend_le_bytes(values: &[Self], out: &mut Vec<u8>);
}

macro_rules! npy_element {
    ($t:ty, $descr:literal) => {
        impl sealed::Sealed for $t {}
        impl NpyElement for $t {
            const DESCR: &'static str = $descr;
            fn extend_le_bytes(values: &[Self], out: &mut Vec<u8>) {
                out.reserve(values.len() * std::mem::size_of::<$t>());
                for v in values {
                    out.extend_from_slice(&v.to_le_bytes());
                }
            }
        }
    };
}
npy_element!(f64, "<f8");
npy_element!(f32, "<f4");
npy_element!(u8, "|u1");
npy_element!(u16, "<u2");

/// Write an `f64` array (`'<f8'`) of the given shape, C order.
pub fn write_npy_f64(path: impl AsRef<Path>, shape: &[usize], data: &[f64]) -> Result<(), IoError> {
    write_npy(path, shape, data)
}

/// Write an `f32` array (`'<f4'`) of the given shape, C order.
pub fn write_npy_f32(path: impl AsRef<Path>, shape: &[usize], data: &[f32]) -> Result<(), IoError> {
    write_npy(path, shape, data)
}

/// Write a `u8` array (`'|u1'`) of the given shape, C order.
pub fn write_npy_u8(path: impl AsRef<Path>, shape: &[usize], data: &[u8]) -> Result<(), IoError> {
    write_npy(path, shape, data)
}

/// Write a `u16` array (`'<u2'`) of the given shape, C order.
pub fn write_npy_u16(path: impl AsRef<Path>, shape: &[usize], data: &[u16]) -> Result<(), IoError> {
    write_npy(path, shape, data)
}

/// Write an array of any [`NpyElement`] type with the given shape, C order.
pub fn write_npy<T: NpyElement>(
    path: impl AsRef<Path>,
    shape: &[usize],
    data: &[T],
) -> Result<(), IoError> {
    let path = path.as_ref();
    let expected = shape
        .iter()
        .try_fold(1usize, |acc, &d| acc.checked_mul(d))
        .ok_or_else(|| IoError::Npy {
            path: path.to_path_buf(),
            reason: format!("the number of elements of shape {shape:?} overflows usize"),
        })?;
    if expected != data.len() {
        return Err(IoError::ShapeMismatch {
            path: path.to_path_buf(),
            shape: shape.to_vec(),
            expected,
            actual: data.len(),
        });
    }
    let header = npy_header(T::DESCR, shape);
    write_atomic_with(path, |w: &mut dyn Write| {
        w.write_all(&header)?;
        let mut buf = Vec::with_capacity(1 << 16);
        for chunk in data.chunks(8192) {
            buf.clear();
            T::extend_le_bytes(chunk, &mut buf);
            w.write_all(&buf)?;
        }
        Ok(())
    })
}

/// Python `repr` of a tuple of integers: `()`, `(5,)`, `(2, 3)`.
fn shape_repr(shape: &[usize]) -> String {
    match shape {
        [] => "()".to_string(),
        [n] => format!("({n},)"),
        _ => {
            let parts: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
            format!("({})", parts.join(", "))
        }
    }
}

/// The dict literal of the header, without padding.
fn header_dict(descr: &str, shape: &[usize]) -> String {
    format!(
        "{{'descr': '{descr}', 'fortran_order': False, 'shape': {}, }}",
        shape_repr(shape)
    )
}

/// Magic + version + header length + padded header; its length is a multiple of 64.
fn npy_header(descr: &str, shape: &[usize]) -> Vec<u8> {
    let dict = header_dict(descr, shape);
    // Same rule as numpy.lib.format._wrap_header: pad with spaces, end with '\n'.
    let wrap = |len_field: usize| {
        let hlen = dict.len() + 1;
        let padlen = ALIGN - ((MAGIC.len() + 2 + len_field + hlen) % ALIGN);
        (hlen + padlen, padlen)
    };
    let (total, padlen, v2) = match wrap(2) {
        (t, p) if t <= u16::MAX as usize => (t, p, false),
        _ => {
            let (t, p) = wrap(4);
            (t, p, true)
        }
    };
    let mut out = Vec::with_capacity(12 + total);
    out.extend_from_slice(MAGIC);
    if v2 {
        out.extend_from_slice(&[2, 0]);
        out.extend_from_slice(&(total as u32).to_le_bytes());
    } else {
        out.extend_from_slice(&[1, 0]);
        out.extend_from_slice(&(total as u16).to_le_bytes());
    }
    out.extend_from_slice(dict.as_bytes());
    out.resize(out.len() + padlen, b' ');
    out.push(b'\n');
    debug_assert_eq!(out.len() % ALIGN, 0);
    out
}

/// Read a `.npy` file as `f64`, returning `(shape, data)` (data in C order).
///
/// Accepts little-endian `'<f8'` and `'<f4'` (plus `'|u1'` and `'<u2'`), converting to `f64`.
pub fn read_npy_f64(path: impl AsRef<Path>) -> Result<(Vec<usize>, Vec<f64>), IoError> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| IoError::io(path, "cannot read", e))?;
    parse_npy_f64(&bytes).map_err(|reason| IoError::Npy {
        path: path.to_path_buf(),
        reason,
    })
}

fn parse_npy_f64(bytes: &[u8]) -> Result<(Vec<usize>, Vec<f64>), String> {
    if bytes.len() < 10 || &bytes[..6] != MAGIC {
        return Err("missing the \\x93NUMPY magic string".to_string());
    }
    let (major, minor) = (bytes[6], bytes[7]);
    let (header_len, start): (usize, usize) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            if bytes.len() < 12 {
                return Err("file too short for a version 2/3 header".to_string());
            }
            let n = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize;
            (n, 12)
        }
        _ => return Err(format!("unsupported format version {major}.{minor}")),
    };
    let data_start = start
        .checked_add(header_len)
        .filter(|&e| e <= bytes.len())
        .ok_or_else(|| format!("header length {header_len} runs past the end of the file"))?;
    let header = std::str::from_utf8(&bytes[start..data_start])
        .map_err(|_| "header is not valid text".to_string())?;
    let h = parse_header(header)?;

    let (size, convert): (usize, fn(&[u8]) -> f64) = match h.descr.as_str() {
        "<f8" => (8, |b| f64::from_le_bytes(b.try_into().unwrap())),
        "<f4" => (4, |b| f32::from_le_bytes(b.try_into().unwrap()) as f64),
        "|u1" | "<u1" => (1, |b| b[0] as f64),
        "<u2" => (2, |b| u16::from_le_bytes(b.try_into().unwrap()) as f64),
        d if d.starts_with('>') => {
            return Err(format!(
                "big-endian dtype '{d}' is not supported; save little-endian data ('<f8' or '<f4')"
            ))
        }
        d => {
            return Err(format!(
                "dtype '{d}' is not supported; expected '<f8' or '<f4' (or '|u1', '<u2')"
            ))
        }
    };
    if h.fortran_order {
        return Err(
            "Fortran-order arrays are not supported (fortran_order: True); save a C-contiguous \
             array, e.g. numpy.ascontiguousarray(a)"
                .to_string(),
        );
    }
    let count = h
        .shape
        .iter()
        .try_fold(1usize, |acc, &d| acc.checked_mul(d))
        .ok_or_else(|| format!("shape {:?} is too large", h.shape))?;
    let need = count
        .checked_mul(size)
        .ok_or_else(|| format!("shape {:?} is too large", h.shape))?;
    let have = bytes.len() - data_start;
    if have < need {
        return Err(format!(
            "file is truncated: shape {:?} of '{}' needs {need} data bytes but only {have} are present",
            h.shape, h.descr
        ));
    }
    if have > need {
        return Err(format!(
            "{} unexpected trailing bytes after the {need} data bytes of shape {:?}",
            have - need,
            h.shape
        ));
    }
    let data = bytes[data_start..]
        .chunks_exact(size)
        .map(convert)
        .collect();
    Ok((h.shape, data))
}

struct Header {
    descr: String,
    fortran_order: bool,
    shape: Vec<usize>,
}

/// Parse the Python dict literal of an NPY header (the subset NumPy writes).
fn parse_header(text: &str) -> Result<Header, String> {
    let mut p = Lexer {
        s: text.as_bytes(),
        i: 0,
    };
    let (mut descr, mut fortran, mut shape) = (None, None, None);
    p.expect(b'{')?;
    loop {
        p.skip_ws();
        if p.eat(b'}') {
            break;
        }
        let key = p.string()?;
        p.expect(b':')?;
        p.skip_ws();
        match key.as_str() {
            "descr" => {
                if p.peek() == Some(b'[') {
                    return Err("structured (record) dtypes are not supported".to_string());
                }
                descr = Some(p.string()?)
            }
            "fortran_order" => fortran = Some(p.boolean()?),
            "shape" => shape = Some(p.int_tuple()?),
            other => return Err(format!("unexpected key '{other}' in header")),
        }
        p.skip_ws();
        if !p.eat(b',') {
            p.expect(b'}')?;
            break;
        }
    }
    let missing = |k: &str| format!("header has no '{k}' entry: {}", text.trim_end());
    Ok(Header {
        descr: descr.ok_or_else(|| missing("descr"))?,
        fortran_order: fortran.ok_or_else(|| missing("fortran_order"))?,
        shape: shape.ok_or_else(|| missing("shape"))?,
    })
}

struct Lexer<'a> {
    s: &'a [u8],
    i: usize,
}

impl Lexer<'_> {
    fn peek(&self) -> Option<u8> {
        self.s.get(self.i).copied()
    }
    fn skip_ws(&mut self) {
        while matches!(self.peek(), Some(b' ' | b'\t' | b'\n' | b'\r')) {
            self.i += 1;
        }
    }
    fn eat(&mut self, c: u8) -> bool {
        self.skip_ws();
        if self.peek() == Some(c) {
            self.i += 1;
            true
        } else {
            false
        }
    }
    fn err(&self, what: &str) -> String {
        let rest = String::from_utf8_lossy(&self.s[self.i.min(self.s.len())..]);
        let rest: String = rest.chars().take(30).collect();
        format!(
            "malformed header: expected {what} at byte {} (near \"{rest}\")",
            self.i
        )
    }
    fn expect(&mut self, c: u8) -> Result<(), String> {
        if self.eat(c) {
            Ok(())
        } else {
            Err(self.err(&format!("'{}'", c as char)))
        }
    }
    fn string(&mut self) -> Result<String, String> {
        self.skip_ws();
        let q = match self.peek() {
            Some(q @ (b'\'' | b'"')) => q,
            _ => return Err(self.err("a quoted string")),
        };
        let start = self.i + 1;
        let len = self.s[start..]
            .iter()
            .position(|&c| c == q)
            .ok_or_else(|| self.err("a closing quote"))?;
        self.i = start + len + 1;
        Ok(String::from_utf8_lossy(&self.s[start..start + len]).into_owned())
    }
    fn boolean(&mut self) -> Result<bool, String> {
        self.skip_ws();
        for (word, v) in [("True", true), ("False", false)] {
            if self.s[self.i..].starts_with(word.as_bytes()) {
                self.i += word.len();
                return Ok(v);
            }
        }
        Err(self.err("True or False"))
    }
    fn int_tuple(&mut self) -> Result<Vec<usize>, String> {
        self.expect(b'(')?;
        let mut dims = Vec::new();
        loop {
            self.skip_ws();
            if self.eat(b')') {
                return Ok(dims);
            }
            let start = self.i;
            while matches!(self.peek(), Some(b'0'..=b'9')) {
                self.i += 1;
            }
            if start == self.i {
                return Err(self.err("a non-negative integer dimension"));
            }
            let digits = std::str::from_utf8(&self.s[start..self.i]).unwrap();
            dims.push(
                digits
                    .parse()
                    .map_err(|_| format!("dimension {digits} is too large"))?,
            );
            // Python 2 era files may write long integers as `3L`.
            if self.peek() == Some(b'L') {
                self.i += 1;
            }
            if !self.eat(b',') {
                self.expect(b')')?;
                return Ok(dims);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn header_text(bytes: &[u8]) -> &str {
        let len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        std::str::from_utf8(&bytes[10..10 + len]).unwrap()
    }

    #[test]
    fn header_matches_numpy_rules() {
        let h = npy_header("<f8", &[2, 3]);
        assert_eq!(&h[..8], b"\x93NUMPY\x01\x00");
        assert_eq!(h.len() % 64, 0);
        assert_eq!(h.len(), 128);
        let text = header_text(&h);
        assert!(text.starts_with("{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }"));
        assert!(text.ends_with('\n'));
        assert_eq!(
            text.trim_end_matches('\n').trim_end_matches(' '),
            "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }"
        );
        assert_eq!(text.len(), 128 - 10);

        let one = npy_header("<f4", &[7]);
        let one = header_text(&one);
        assert!(one.starts_with("{'descr': '<f4', 'fortran_order': False, 'shape': (7,), }  "));
        let scalar = npy_header("|u1", &[]);
        let scalar = header_text(&scalar);
        assert!(scalar.starts_with("{'descr': '|u1', 'fortran_order': False, 'shape': (), }  "));
    }

    #[test]
    fn header_padding_when_already_aligned() {
        // numpy adds a full 64 bytes of padding when the unpadded header is already aligned.
        for ndim in 0..40 {
            let shape = vec![1234567usize; ndim];
            let h = npy_header("<f8", &shape);
            assert_eq!(h.len() % 64, 0);
            let dict = header_dict("<f8", &shape);
            let pad = h.len() - 10 - dict.len() - 1;
            assert!((1..=64).contains(&pad), "pad {pad}");
            assert_eq!(pad, 64 - (10 + dict.len() + 1) % 64);
        }
    }

    #[test]
    fn golden_bytes_f64() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("a.npy");
        write_npy_f64(&p, &[2], &[1.0, -2.5]).unwrap();
        let b = std::fs::read(&p).unwrap();
        // Exact file numpy.save(p, np.array([1.0, -2.5])) would produce, apart from the amount of
        // space padding (numpy >= 1.24 reserves extra room; both are valid).
        let mut expected = b"\x93NUMPY\x01\x00\x76\x00".to_vec();
        let dict = b"{'descr': '<f8', 'fortran_order': False, 'shape': (2,), }";
        expected.extend_from_slice(dict);
        expected.resize(expected.len() + 128 - 10 - dict.len() - 1, b' ');
        expected.push(b'\n');
        expected.extend_from_slice(&1.0f64.to_le_bytes());
        expected.extend_from_slice(&(-2.5f64).to_le_bytes());
        assert_eq!(b, expected);
    }

    #[test]
    fn round_trips() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("x.npy");
        let d: Vec<f64> = (0..24).map(|i| i as f64 * 0.1 - 1.0).collect();
        write_npy_f64(&p, &[2, 3, 4], &d).unwrap();
        assert_eq!(read_npy_f64(&p).unwrap(), (vec![2, 3, 4], d.clone()));

        let f: Vec<f32> = d.iter().map(|&x| x as f32).collect();
        write_npy_f32(&p, &[4, 6], &f).unwrap();
        let (s, back) = read_npy_f64(&p).unwrap();
        assert_eq!(s, vec![4, 6]);
        assert_eq!(back, f.iter().map(|&x| x as f64).collect::<Vec<_>>());

        write_npy_u8(&p, &[3], &[0, 128, 255]).unwrap();
        assert_eq!(
            read_npy_f64(&p).unwrap(),
            (vec![3], vec![0.0, 128.0, 255.0])
        );
        write_npy_u16(&p, &[1, 2], &[1, 65535]).unwrap();
        assert_eq!(read_npy_f64(&p).unwrap(), (vec![1, 2], vec![1.0, 65535.0]));

        // 0-d scalar and empty arrays.
        write_npy_f64(&p, &[], &[42.0]).unwrap();
        assert_eq!(read_npy_f64(&p).unwrap(), (vec![], vec![42.0]));
        write_npy_f64(&p, &[0, 5], &[]).unwrap();
        assert_eq!(read_npy_f64(&p).unwrap(), (vec![0, 5], vec![]));

        // Special values survive bit-exactly.
        let special = [f64::NAN, f64::INFINITY, -0.0, f64::MIN_POSITIVE, f64::MAX];
        write_npy_f64(&p, &[5], &special).unwrap();
        let (_, back) = read_npy_f64(&p).unwrap();
        for (a, b) in special.iter().zip(&back) {
            assert_eq!(a.to_bits(), b.to_bits());
        }
    }

    #[test]
    fn shape_mismatch_is_an_error() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("bad.npy");
        let e = write_npy_f64(&p, &[2, 3], &[1.0; 5]).unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains("bad.npy") && msg.contains("[2, 3]") && msg.contains('5'),
            "{msg}"
        );
        assert!(!p.exists());
        assert!(write_npy_f64(&p, &[usize::MAX, 3], &[]).is_err());
        assert!(write_npy_f64(&p, &[], &[]).is_err());
    }

    /// Build a file with an arbitrary header (as other writers / numpy versions might).
    fn raw(version: u8, dict: &str, data: &[u8]) -> Vec<u8> {
        let mut v = MAGIC.to_vec();
        v.extend_from_slice(&[version, 0]);
        if version == 1 {
            v.extend_from_slice(&(dict.len() as u16).to_le_bytes());
        } else {
            v.extend_from_slice(&(dict.len() as u32).to_le_bytes());
        }
        v.extend_from_slice(dict.as_bytes());
        v.extend_from_slice(data);
        v
    }

    #[test]
    fn reader_accepts_numpy_variants() {
        let data: Vec<u8> = [1.5f64, 2.5].iter().flat_map(|x| x.to_le_bytes()).collect();
        // numpy >= 1.24 reserves growth space; key order and spacing may differ; v2/v3 headers.
        for dict in [
            "{'descr': '<f8', 'fortran_order': False, 'shape': (2,), }                      \n",
            "{'shape': (2,), 'fortran_order': False, 'descr': '<f8'}\n",
            "{\"descr\":\"<f8\",\"fortran_order\":False,\"shape\":(2L,)}",
            "{'descr': '<f8', 'fortran_order': False, 'shape': (1, 2), }\n",
        ] {
            for version in [1, 2, 3] {
                let (shape, v) = parse_npy_f64(&raw(version, dict, &data)).unwrap();
                assert_eq!(v, vec![1.5, 2.5], "{dict}");
                assert_eq!(shape.iter().product::<usize>(), 2);
            }
        }
    }

    #[test]
    fn reader_errors_are_clear() {
        let f8: Vec<u8> = [1.5f64, 2.5].iter().flat_map(|x| x.to_le_bytes()).collect();
        let cases: &[(Vec<u8>, &str)] = &[
            (b"PK\x03\x04 not npy".to_vec(), "magic"),
            (
                raw(
                    1,
                    "{'descr': '>f8', 'fortran_order': False, 'shape': (2,), }",
                    &f8,
                ),
                "big-endian",
            ),
            (
                raw(
                    1,
                    "{'descr': '<i8', 'fortran_order': False, 'shape': (2,), }",
                    &f8,
                ),
                "'<i8' is not supported",
            ),
            (
                raw(
                    1,
                    "{'descr': '<f8', 'fortran_order': True, 'shape': (2,), }",
                    &f8,
                ),
                "Fortran",
            ),
            (
                raw(
                    1,
                    "{'descr': '<f8', 'fortran_order': False, 'shape': (3,), }",
                    &f8,
                ),
                "truncated",
            ),
            (
                raw(
                    1,
                    "{'descr': '<f8', 'fortran_order': False, 'shape': (1,), }",
                    &f8,
                ),
                "trailing",
            ),
            (
                raw(
                    1,
                    "{'descr': [('a', '<f8')], 'fortran_order': False, 'shape': (1,), }",
                    &f8,
                ),
                "structured",
            ),
            (
                raw(1, "{'descr': '<f8', 'shape': (2,), }", &f8),
                "no 'fortran_order'",
            ),
            (
                raw(
                    1,
                    "{'descr': '<f8', 'fortran_order': False, 'shape': (2, x), }",
                    &f8,
                ),
                "malformed",
            ),
            (raw(9, "{}", &f8), "version 9.0"),
            (b"\x93NUMPY\x01\x00\xff\x00{".to_vec(), "runs past the end"),
        ];
        for (bytes, needle) in cases {
            let e = parse_npy_f64(bytes).unwrap_err();
            assert!(e.contains(needle), "expected '{needle}' in: {e}");
        }
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("broken.npy");
        std::fs::write(&p, b"nope").unwrap();
        let msg = read_npy_f64(&p).unwrap_err().to_string();
        assert!(msg.contains("broken.npy") && msg.contains("magic"), "{msg}");
        let msg = read_npy_f64(tmp.path().join("missing.npy"))
            .unwrap_err()
            .to_string();
        assert!(msg.contains("missing.npy"), "{msg}");
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        #[test]
        fn prop_round_trip(shape in proptest::collection::vec(0usize..5, 0..4), seed in any::<u64>()) {
            let n: usize = shape.iter().product();
            let data: Vec<f64> = (0..n)
                .map(|i| f64::from_bits(seed.rotate_left(i as u32).wrapping_mul(0x9E37_79B9_7F4A_7C15)))
                .collect();
            let tmp = tempfile::tempdir().unwrap();
            let p = tmp.path().join("p.npy");
            write_npy_f64(&p, &shape, &data).unwrap();
            let bytes = std::fs::read(&p).unwrap();
            prop_assert_eq!(npy_header("<f8", &shape).len() % 64, 0);
            prop_assert_eq!(bytes.len(), npy_header("<f8", &shape).len() + 8 * n);
            let (s, back) = read_npy_f64(&p).unwrap();
            prop_assert_eq!(s, shape);
            prop_assert_eq!(
                back.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                data.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
            );
        }
    }
}
