//! NumPy arguments in, NumPy results out.
//!
//! Inputs are borrowed in place (no copy): an argument must be a `numpy.ndarray` of the documented dtype,
//! number of dimensions and C-contiguous layout, else a `ValueError` names the argument, the expected and
//! the actual dtype/shape. Outputs are Rust vectors handed to NumPy as they are (one allocation).
use crate::errors::value_error;
use numpy::{Element, IntoPyArray, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArray, PyUntypedArrayMethods};
use pyo3::prelude::*;

/// A borrowed, checked input array: its shape and a slice of its data.
pub struct Input<'py, T: Element> {
    array: PyReadonlyArrayDyn<'py, T>,
    pub shape: Vec<usize>,
}

impl<T: Element> Input<'_, T> {
    pub fn slice(&self) -> &[T] {
        self.array.as_slice().expect("checked C-contiguous")
    }
}

fn describe(obj: &Bound<'_, PyAny>) -> String {
    match obj.downcast::<PyUntypedArray>() {
        Ok(a) => format!("{} array of shape {:?}", a.dtype(), a.shape()),
        Err(_) => format!("{}", obj.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "?".into())),
    }
}

/// `obj` as a C-contiguous array of `T` (`dtype` its NumPy name) with `ndim` dimensions; `expect` describes
/// the shape for the message (e.g. "(H, W, B)").
pub fn input<'py, T: Element>(name: &str, obj: &Bound<'py, PyAny>, dtype: &str, ndim: usize, expect: &str) -> PyResult<Input<'py, T>> {
    let untyped = obj
        .downcast::<PyUntypedArray>()
        .map_err(|_| value_error(format!("{name}: expected a numpy.ndarray of {dtype} with shape {expect}, got {}", describe(obj))))?;
    let typed = obj
        .downcast::<PyArrayDyn<T>>()
        .map_err(|_| value_error(format!("{name}: expected dtype {dtype} with shape {expect}, got {} (convert with .astype(numpy.{dtype}))", describe(obj))))?;
    if untyped.ndim() != ndim {
        return Err(value_error(format!("{name}: expected {ndim} dimensions {expect}, got shape {:?}", untyped.shape())));
    }
    if !untyped.is_c_contiguous() {
        return Err(value_error(format!("{name}: the {dtype} array of shape {:?} is not C-contiguous (pass numpy.ascontiguousarray({name}))", untyped.shape())));
    }
    let shape = untyped.shape().to_vec();
    let array = typed.try_readonly().map_err(|e| value_error(format!("{name}: cannot borrow the array: {e}")))?;
    Ok(Input { array, shape })
}

/// Check every value is finite; the message names the argument and the first bad index.
pub fn check_finite<T: Copy + Into<f64>>(name: &str, values: &[T], shape: &[usize]) -> PyResult<()> {
    if let Some(i) = values.iter().position(|v| !(*v).into().is_finite()) {
        return Err(value_error(format!("{name}: value {} at index {:?} is not finite", (values[i]).into(), index_of(i, shape))));
    }
    Ok(())
}

/// The C-order index of flat position `i` in an array of `shape` (for messages).
fn index_of(i: usize, shape: &[usize]) -> Vec<usize> {
    let mut idx = vec![0usize; shape.len()];
    let mut r = i;
    for (k, d) in shape.iter().enumerate().rev() {
        idx[k] = r % d.max(&1);
        r /= d.max(&1);
    }
    idx
}

/// [`check_finite`], then |v| ≤ [`diffcassi::limits::MAX_SCENE_VALUE`] (f32's range / 10⁹, the scene radiance
/// limit the CLI applies to acquisitions too): the operators and solvers sum in f32, so a larger value
/// (3e38, 1e36) overflowed to inf or NaN in their outputs (a held-out battery); refused, naming the index.
/// Float64 values are checked before they are narrowed to float32, so the message shows the value given (1e300),
/// not the inf the conversion would make of it.
pub fn check_bounded<T: Copy + Into<f64> + std::fmt::LowerExp>(name: &str, values: &[T], shape: &[usize]) -> PyResult<()> {
    check_finite(name, values, shape)?;
    let max = diffcassi::limits::MAX_SCENE_VALUE;
    if let Some(i) = values.iter().position(|&v| v.into().abs() > max) {
        return Err(value_error(format!("{name}: value {:e} at index {:?} is beyond ±{max:.3e} (f32's range / 10⁹) that the operators' and solvers' f32 sums allow; rescale it", values[i], index_of(i, shape))));
    }
    Ok(())
}

/// A Rust vector as a NumPy array of `shape` (no copy).
pub fn output<'py, T: Element>(py: Python<'py>, data: Vec<T>, shape: &[usize]) -> PyResult<Bound<'py, PyArrayDyn<T>>> {
    let a = ndarray::ArrayD::from_shape_vec(ndarray::IxDyn(shape), data).map_err(|e| value_error(format!("internal: result shape {shape:?}: {e}")))?;
    Ok(a.into_pyarray(py))
}

/// A float64 vector (e.g. wavelengths) from any Python sequence or array of numbers, checked finite.
pub fn f64_list(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<Vec<f64>> {
    let v: Vec<f64> = if let Ok(a) = obj.downcast::<PyUntypedArray>() {
        if a.ndim() != 1 {
            return Err(value_error(format!("{name}: expected a 1-D sequence of numbers, got shape {:?}", a.shape())));
        }
        if numpy::PyArrayDescrMethods::kind(&a.dtype()) == b'b' {
            return Err(value_error(format!("{name}: expected a sequence of numbers, got an array of bools")));
        }
        obj.call_method1("astype", ("float64",))?.extract::<Vec<f64>>()?
    } else {
        // A bool is an int to Python: `[True, 520]` was 1 nm and 520 nm.
        if let Ok(items) = obj.try_iter() {
            if let Some(b) = items.flatten().find(|i| is_bool(i)) {
                return Err(value_error(format!("{name}: expected a sequence of numbers, got {} in it", short_repr(&b))));
            }
        }
        obj.extract::<Vec<f64>>().map_err(|_| value_error(format!("{name}: expected a sequence of numbers, got {}", describe(obj))))?
    };
    check_finite(name, &v, &[v.len()])?;
    Ok(v)
}

/// A Python bool or a NumPy one (`np.True_`, whose type is `numpy.bool` or, before NumPy 2, `numpy.bool_`: not a
/// subclass of `bool`, and read as 1.0 by a float extraction).
pub fn is_bool(v: &Bound<'_, PyAny>) -> bool {
    v.is_instance_of::<pyo3::types::PyBool>() || v.get_type().name().is_ok_and(|n| n.to_string() == "bool_" || n.to_string() == "bool")
}

/// A real-number argument: a Python or NumPy integer or float, finite or not (the caller checks its range);
/// a bool (`pitch_mm=True` was 1 mm), a string or anything else is a `DiffcassiValueError` naming the argument.
pub fn real_arg(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<f64> {
    let bad = || value_error(format!("{name}: expected a number, got {}", short_repr(obj)));
    if is_bool(obj) || obj.is_instance_of::<pyo3::types::PyString>() {
        return Err(bad());
    }
    obj.extract::<f64>().map_err(|_| bad())
}

/// A short `repr` of a Python object for messages (at most ~60 characters: `2**1000` is not printed whole).
pub fn short_repr(obj: &Bound<'_, PyAny>) -> String {
    let ty = obj.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "?".into());
    let r = obj.repr().map(|r| r.to_string()).unwrap_or_default();
    let r = if r.chars().count() > 60 { format!("{}… ({} characters)", r.chars().take(40).collect::<String>(), r.chars().count()) } else { r };
    format!("{ty} {r}")
}

/// An integer argument in `lo..=hi` (anything `operator.index` accepts: Python and NumPy integers). A
/// float, a string or an integer out of range (e.g. `2**70`, which PyO3 would report as a bare
/// `OverflowError`) is a `DiffcassiValueError` naming the argument, its value and the range.
pub fn uint_arg(name: &str, obj: &Bound<'_, PyAny>, lo: u64, hi: u64) -> PyResult<u64> {
    let bad = || value_error(format!("{name}: expected an integer in {lo}..={hi}, got {}", short_repr(obj)));
    if obj.is_instance_of::<pyo3::types::PyBool>() {
        return Err(bad());
    }
    let v: u64 = obj.extract().map_err(|_| bad())?;
    if v < lo || v > hi {
        return Err(bad());
    }
    Ok(v)
}

/// A size argument (`height`, `width`, a count): an integer in `1..=usize::MAX` (the memory and ray budgets
/// bound it further, before anything is allocated).
pub fn size_arg(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<usize> {
    Ok(uint_arg(name, obj, 1, usize::MAX as u64)? as usize)
}

/// What a seed is, as every seed refusal states it (keyword settings through `settings::get`, positional
/// arguments through [`seed_arg`]): the whole range of a u64. "an integer ≥ 0" refused 2**64, a value it
/// allowed (a held-out battery, round 20).
pub const SEED: &str = "an integer in 0..=18446744073709551615";
/// A count setting's range as refusals state it (planes, rays, sizes, iterations: `usize`, 64-bit).
pub const COUNT: &str = "an integer in 1..=18446744073709551615";

/// A seed: any integer in `0..=2⁶⁴ − 1` (refused as [`SEED`] says).
pub fn seed_arg(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<u64> {
    uint_arg(name, obj, 0, u64::MAX)
}

/// A caller-provided output array: float32, C-contiguous, writeable, exactly `shape`; borrowed for
/// writing (rust-numpy refuses it while another borrow of the same memory is alive). The message names
/// the argument.
pub fn output_arg<'py>(name: &str, obj: &Bound<'py, PyAny>, shape: &[usize]) -> PyResult<numpy::PyReadwriteArrayDyn<'py, f32>> {
    let a = obj
        .downcast::<PyArrayDyn<f32>>()
        .map_err(|_| value_error(format!("{name}: expected a float32 numpy.ndarray of shape {shape:?}, got {}", describe(obj))))?;
    if a.shape() != shape {
        return Err(value_error(format!("{name}: expected shape {shape:?}, got {:?}", a.shape())));
    }
    if !a.is_c_contiguous() {
        return Err(value_error(format!("{name}: the float32 array of shape {shape:?} is not C-contiguous")));
    }
    a.try_readwrite().map_err(|e| value_error(format!("{name}: cannot borrow the array for writing (read-only, or the same memory as an input?): {e}")))
}
