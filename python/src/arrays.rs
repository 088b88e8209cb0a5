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
        let mut idx = vec![0usize; shape.len()];
        let mut r = i;
        for (k, d) in shape.iter().enumerate().rev() {
            idx[k] = r % d.max(&1);
            r /= d.max(&1);
        }
        return Err(value_error(format!("{name}: value {} at index {idx:?} is not finite", (values[i]).into())));
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
        obj.call_method1("astype", ("float64",))?.extract::<Vec<f64>>()?
    } else {
        obj.extract::<Vec<f64>>().map_err(|_| value_error(format!("{name}: expected a sequence of numbers, got {}", describe(obj))))?
    };
    check_finite(name, &v, &[v.len()])?;
    Ok(v)
}
