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
//! (and the integer types written here, `'|u1'` and `'<u2'`), all converted to `f64`, returned in C
//! order (Fortran-order files are read too), from format versions 1.0, 2.0 and 3.0. Big-endian data,
//! other dtypes, malformed headers, truncated files and trailing bytes after the data are reported as
//! [`IoError::Npy`] naming the file and the problem.
//!
//! **What is the `ndarray-npy` crate's and what is ours.** The reader parses the header and checks and
//! views the data with `ndarray-npy` (its zero-copy `view_npy`, which compares the data size with the
//! buffer before allocating anything, so a header claiming 10¹² elements is an error, not an allocation),
//! one element type after the other. Our own code is only: the magic/version/header-length prefix (so
//! that a non-NPY file or a header running past the end is named as such), an 8-byte-aligned copy of the
//! file (the view needs aligned data), blanking Python 2's `3L` long-integer suffix (its Python-3 literal
//! parser rejects it), and turning its errors into this module's messages. The **writer stays our own**:
//! `ndarray-npy` writes the header dict without NumPy's trailing `, ` (`{..., 'shape': (2, 3)}` instead
//! of `{..., 'shape': (2, 3), }`), so its files would differ byte for byte from NumPy's and from the
//! files this crate has always written (pinned by the golden tests below and by tests elsewhere).
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

use ndarray::ArrayViewD;
use ndarray_npy::{ViewNpyError, ViewNpyExt};
use py_literal::Value as PyValue;

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
/// Accepts little-endian `'<f8'` and `'<f4'` (plus `'|u1'` and `'<u2'`), converting to `f64`, in C or
/// Fortran order (returned in C order). The memory the result needs (8 bytes per element, counted from the
/// header, plus the file held while converting) is checked against the budget before it is allocated.
pub fn read_npy_f64(path: impl AsRef<Path>) -> Result<(Vec<usize>, Vec<f64>), IoError> {
    let path = path.as_ref();
    let bytes = super::input::read_input(path, super::input::binary_limit())?;
    let result = with_view(bytes, |view, file_len| {
        check_output_memory(&view, file_len, 8)?;
        Ok(match view {
            AnyView::F64(a) => convert(a, |v| v),
            AnyView::F32(a) => convert(a, f64::from),
            AnyView::U8(a) => convert(a, f64::from),
            AnyView::U16(a) => convert(a, f64::from),
        })
    });
    split_errors(path, result)
}

/// Read a `.npy` file straight into `f32` (the precision spectral cubes are held in), `(shape, data)` in C
/// order, without an `f64` copy: the peak is the file plus 4 bytes per element, counted from the header's
/// shape and checked against the memory budget before the cube is allocated (an 8-bit cube went through an
/// `f64` vector and peaked at ≈ 12× its file, 3× over `--max-memory-gb`; a held-out battery, round 17).
/// An `'<f8'` value beyond the float32 range (±3.4·10³⁸) is an error naming it and its index, not a
/// silent `inf`.
pub fn read_npy_f32(path: impl AsRef<Path>) -> Result<(Vec<usize>, Vec<f32>), IoError> {
    let path = path.as_ref();
    let bytes = super::input::read_input(path, super::input::binary_limit())?;
    let result = with_view(bytes, |view, file_len| {
        check_output_memory(&view, file_len, 4)?;
        Ok(match view {
            AnyView::F64(a) => {
                let shape = a.shape().to_vec();
                let mut out = Vec::with_capacity(a.len());
                for (i, &v) in a.iter().enumerate() {
                    let f = v as f32;
                    if v.is_finite() && !f.is_finite() {
                        return Err(format!("the value at {} is {v:e}, beyond the float32 range (±{:.1e}) the cubes are held in", index_text(&shape, i), f32::MAX));
                    }
                    out.push(f);
                }
                (shape, out)
            }
            AnyView::F32(a) => convert(a, |v| v),
            AnyView::U8(a) => convert(a, f32::from),
            AnyView::U16(a) => convert(a, f32::from),
        })
    });
    split_errors(path, result)
}

/// A format error as [`IoError::Npy`] ("not a supported .npy file"), a content error (a value, the memory
/// budget) as [`IoError::NpyContent`].
fn split_errors<T>(path: &Path, result: Result<Result<T, String>, String>) -> Result<T, IoError> {
    match result {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(reason)) => Err(IoError::NpyContent { path: path.to_path_buf(), reason }),
        Err(reason) => Err(IoError::Npy { path: path.to_path_buf(), reason }),
    }
}

/// Element `flat` (C order) of an array of `shape`, for messages: `row 2, col 2, band 2` for a 3-D cube,
/// else `index [i, j, …]`.
fn index_text(shape: &[usize], flat: usize) -> String {
    let mut idx = vec![0usize; shape.len()];
    let mut rest = flat;
    for (k, &d) in shape.iter().enumerate().rev() {
        idx[k] = rest % d.max(1);
        rest /= d.max(1);
    }
    match idx.as_slice() {
        [r, c, b] => format!("row {r}, col {c}, band {b}"),
        _ => format!("index {idx:?}"),
    }
}

/// The file's array, one element type after the other (a view into the file's bytes).
enum AnyView<'a> {
    F64(ArrayViewD<'a, f64>),
    F32(ArrayViewD<'a, f32>),
    U8(ArrayViewD<'a, u8>),
    U16(ArrayViewD<'a, u16>),
}

impl AnyView<'_> {
    fn shape_and_descr(&self) -> (Vec<usize>, &'static str) {
        match self {
            AnyView::F64(a) => (a.shape().to_vec(), "<f8"),
            AnyView::F32(a) => (a.shape().to_vec(), "<f4"),
            AnyView::U8(a) => (a.shape().to_vec(), "|u1"),
            AnyView::U16(a) => (a.shape().to_vec(), "<u2"),
        }
    }
}

/// `iter` walks the logical (C) order whatever the memory order (Fortran files included).
fn convert<T: Copy, U>(a: ArrayViewD<'_, T>, f: impl Fn(T) -> U) -> (Vec<usize>, Vec<U>) {
    (a.shape().to_vec(), a.iter().map(|v| f(*v)).collect())
}

/// The converted array (`out_bytes` per element, counted from the header's shape) plus the file held while
/// converting, against the memory budget ([`crate::limits::check_memory`]), before it is allocated.
fn check_output_memory(view: &AnyView<'_>, file_len: usize, out_bytes: usize) -> Result<(), String> {
    let (shape, descr) = view.shape_and_descr();
    let n: f64 = shape.iter().map(|&d| d as f64).product();
    let what = format!("the {shape:?} '{descr}' array ({out_bytes} bytes per element once converted, plus the {file_len}-byte file)");
    crate::limits::check_memory(&what, file_len as f64 + n * out_bytes as f64).map_err(|e| e.to_string())
}

/// Offset of the data: the header's declared end, checked to lie inside the file (the prefix is read
/// here so that these two errors name the problem exactly; everything else is `ndarray-npy`'s).
fn data_offset(bytes: &[u8]) -> Result<usize, String> {
    if bytes.len() < 10 || &bytes[..6] != MAGIC {
        return Err("missing the \\x93NUMPY magic string".to_string());
    }
    let (header_len, start): (usize, usize) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize, 12),
        2 | 3 => return Err("file too short for a version 2/3 header".to_string()),
        major => return Err(format!("unsupported format version {major}.{}", bytes[7])),
    };
    start
        .checked_add(header_len)
        .filter(|&e| e <= bytes.len())
        .ok_or_else(|| format!("header length {header_len} runs past the end of the file"))
}

/// The file's array through `ndarray-npy`'s zero-copy view (sizes are checked against the buffer before
/// anything is allocated), one element type after the other, handed to `f` with the file's length.
/// `Err` is a format error (the file is no NPY this reader takes); `Ok(Err)` is `f`'s (the content).
fn with_view<R, E>(mut bytes: Vec<u8>, f: impl FnOnce(AnyView<'_>, usize) -> Result<R, E>) -> Result<Result<R, E>, String> {
    let offset = data_offset(&bytes)?;
    let file_len = bytes.len();
    // Python 2's NumPy wrote long dimensions as `3L`, which ndarray-npy's (Python 3) literal parser
    // rejects: blank each such `L` (same length, so the data offset is unchanged).
    for i in 1..offset {
        if bytes[i] == b'L' && bytes[i - 1].is_ascii_digit() {
            bytes[i] = b' ';
        }
    }
    // The view needs the data aligned for its element type. NumPy pads headers to 64 bytes and the file's
    // buffer is allocated aligned, so the data usually is; otherwise copy the file once so that the data
    // starts on an 8-byte boundary (and drop the original before anything is converted).
    let mut words: Vec<u64>;
    let buf: &[u8] = if (bytes.as_ptr() as usize + offset) % 8 == 0 {
        &bytes
    } else {
        let pad = (8 - offset % 8) % 8;
        words = vec![0u64; (pad + file_len).div_ceil(8)];
        // SAFETY: a u64 buffer viewed as bytes (u8 has no alignment or validity requirement).
        let aligned: &mut [u8] = unsafe { std::slice::from_raw_parts_mut(words.as_mut_ptr() as *mut u8, words.len() * 8) };
        aligned[pad..pad + file_len].copy_from_slice(&bytes);
        drop(std::mem::take(&mut bytes));
        &aligned[pad..pad + file_len]
    };
    macro_rules! attempt {
        ($t:ty, $v:ident) => {
            match ArrayViewD::<$t>::view_npy(buf) {
                Ok(a) => return Ok(f(AnyView::$v(a), file_len)),
                Err(ViewNpyError::WrongDescriptor(_)) => {}
                Err(e) => return Err(describe(e)),
            }
        };
    }
    attempt!(f64, F64);
    attempt!(f32, F32);
    attempt!(u8, U8);
    match ArrayViewD::<u16>::view_npy(buf) {
        Ok(a) => Ok(f(AnyView::U16(a), file_len)),
        Err(e) => Err(describe(e)),
    }
}

/// [`read_npy_f64`] on bytes in memory (tests).
#[cfg(test)]
fn parse_npy_f64(bytes: &[u8]) -> Result<(Vec<usize>, Vec<f64>), String> {
    with_view(bytes.to_vec(), |view, _| -> Result<_, String> {
        Ok(match view {
            AnyView::F64(a) => convert(a, |v| v),
            AnyView::F32(a) => convert(a, f64::from),
            AnyView::U8(a) => convert(a, f64::from),
            AnyView::U16(a) => convert(a, f64::from),
        })
    })?
}

/// `ndarray-npy`'s error as this module's message.
fn describe(e: ViewNpyError) -> String {
    match e {
        ViewNpyError::WrongDescriptor(PyValue::String(d)) if d.starts_with('>') => {
            format!("big-endian dtype '{d}' is not supported; save little-endian data ('<f8' or '<f4')")
        }
        ViewNpyError::NonNativeEndian => "big-endian data is not supported; save little-endian data ('<f8' or '<f4')".to_string(),
        ViewNpyError::WrongDescriptor(PyValue::String(d)) => {
            format!("dtype '{d}' is not supported; expected '<f8' or '<f4' (or '|u1', '<u2')")
        }
        ViewNpyError::WrongDescriptor(d) => format!("structured (record) dtypes are not supported (descr {d})"),
        ViewNpyError::MissingBytes(n) => format!("file is truncated: {n} data bytes are missing for the header's shape and dtype"),
        ViewNpyError::ExtraBytes(n) => format!("{n} unexpected trailing bytes after the data of the header's shape and dtype"),
        ViewNpyError::LengthOverflow => "the header's shape is too large".to_string(),
        // ndarray-npy 0.9 names a missing `shape` key "shaper" (a typo in its message; its error type is
        // not exported, so the message is matched).
        ViewNpyError::ParseHeader(p) if p.to_string().starts_with("missing key: ") => {
            let k = p.to_string()["missing key: ".len()..].to_string();
            format!("malformed header: missing key '{}' (a header needs 'descr', 'fortran_order' and 'shape')", if k == "shaper" { "shape" } else { k.as_str() })
        }
        ViewNpyError::ParseHeader(p) => format!("malformed header: {p}"),
        other => format!("unreadable data: {other}"),
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

    /// Build a file with an arbitrary header (as other writers / numpy versions might), terminated by the
    /// newline the format requires.
    fn raw(version: u8, dict: &str, data: &[u8]) -> Vec<u8> {
        let nl = if dict.ends_with('\n') { "" } else { "\n" };
        raw_exact(version, &format!("{dict}{nl}"), data)
    }

    /// [`raw`] without the newline.
    fn raw_exact(version: u8, dict: &str, data: &[u8]) -> Vec<u8> {
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
    fn reader_reads_fortran_order_as_c_order() {
        // numpy.asfortranarray([[1, 2, 3], [4, 5, 6]]): memory order 1 4 2 5 3 6.
        let data: Vec<u8> = [1.0f64, 4.0, 2.0, 5.0, 3.0, 6.0].iter().flat_map(|x| x.to_le_bytes()).collect();
        let (shape, v) = parse_npy_f64(&raw(1, "{'descr': '<f8', 'fortran_order': True, 'shape': (2, 3), }", &data)).unwrap();
        assert_eq!(shape, vec![2, 3]);
        assert_eq!(v, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
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
                raw_exact(1, "{'descr': '<f8', 'fortran_order': False, 'shape': (2,), }", &f8),
                "newline missing",
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
                "missing key 'fortran_order'",
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
