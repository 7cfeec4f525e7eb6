//! The Python binding `lightemma._core`: thin wrappers that borrow NumPy arrays,
//! release the GIL for large batches and return NumPy arrays. Every error is a
//! [`CoreError`], mapped to lightemma's exception classes in one place (`python/errors.rs`).
//!
//! One module per domain of the core, each with a `register` that adds its functions and constants to `_core`:
//! `parse` (answers → actions), `intent`, `objects`, `kinematics`, `metrics`, `stats`, `safety`, `planning_sim`,
//! `planning_scores`; `errors` maps [`CoreError`] to Python. This file holds what they share: the GIL policy
//! ([`maybe_detach`]) and the borrowing of arrays and strings.

use numpy::ndarray::Array3;
use numpy::{PyReadonlyArray1, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::pybacked::PyBackedStr;
use pyo3::types::{PyList, PyString};

use crate::definitions;
use crate::error::CoreError;

mod errors;
mod intent;
mod kinematics;
mod metrics;
mod objects;
mod parse;
mod planning_scores;
mod planning_sim;
mod safety;
mod stats;

/// Batches at least this large run with the GIL released.
const DETACH_MIN_FRAMES: usize = 2048;

/// Run `f` with the GIL released when the batch is large enough to be worth it.
fn maybe_detach<T, F>(py: Python<'_>, frames: usize, f: F) -> T
where
    F: FnOnce() -> T + Send,
    T: Send,
{
    if frames >= DETACH_MIN_FRAMES {
        py.detach(f)
    } else {
        f()
    }
}

/// Borrow a C-contiguous float64 array of shape (N, T, 2); returns (data, N, T).
fn frames_view<'a>(
    array: &'a PyReadonlyArrayDyn<'_, f64>,
    name: &str,
) -> PyResult<(&'a [f64], usize, usize)> {
    let shape = array.shape();
    if shape.len() != 3 || shape[2] != 2 {
        return Err(
            CoreError::Shape(format!("{name} must have shape (N, T, 2), got {shape:?}")).into(),
        );
    }
    let data = array
        .as_slice()
        .map_err(|_| errors::shape(format!("{name} must be C-contiguous")))?;
    Ok((data, shape[0], shape[1]))
}

fn shape_to_3d(data: Vec<f64>, n: usize, t: usize) -> PyResult<Array3<f64>> {
    Array3::from_shape_vec((n, t, 2), data).map_err(|e| errors::shape(e.to_string()))
}

/// An answer's text: borrowed from the Python string, or a lossy copy when the
/// string holds lone surrogates (which have no UTF-8 form).
enum Text {
    Backed(PyBackedStr),
    Lossy(String),
}

impl AsRef<str> for Text {
    fn as_ref(&self) -> &str {
        match self {
            Text::Backed(s) => s,
            Text::Lossy(s) => s,
        }
    }
}

/// The texts of a list of str; a non-str item is a `ValueError` naming it.
fn texts_of(list: &Bound<'_, PyList>) -> PyResult<Vec<Text>> {
    let mut texts = Vec::with_capacity(list.len());
    for (i, item) in list.iter().enumerate() {
        let s = item.cast_into::<PyString>().map_err(|e| {
            let type_name = e
                .into_inner()
                .get_type()
                .name()
                .map_or_else(|_| "?".to_owned(), |n| n.to_string());
            errors::argument(format!("texts must be str: item {i} is {type_name}"))
        })?;
        texts.push(match PyBackedStr::try_from(s.clone()) {
            Ok(backed) => Text::Backed(backed),
            Err(_) => Text::Lossy(s.to_string_lossy().into_owned()),
        });
    }
    Ok(texts)
}

/// Borrow a C-contiguous 1-D array.
fn slice1<'a, T: numpy::Element>(
    array: &'a PyReadonlyArray1<'_, T>,
    name: &str,
) -> PyResult<&'a [T]> {
    array
        .as_slice()
        .map_err(|_| errors::shape(format!("{name} must be C-contiguous")))
}

/// Borrow a C-contiguous array of the given trailing shape; returns (data, leading extents).
fn view_nd<'a, T: numpy::Element>(
    array: &'a PyReadonlyArrayDyn<'_, T>,
    name: &str,
    ndim: usize,
    trailing: &[usize],
    expected: &str,
) -> PyResult<(&'a [T], Vec<usize>)> {
    let shape = array.shape();
    let tail_ok = shape.len() == ndim
        && shape[ndim - trailing.len()..]
            .iter()
            .zip(trailing)
            .all(|(a, b)| a == b);
    if !tail_ok {
        return Err(
            CoreError::Shape(format!("{name} must have shape {expected}, got {shape:?}")).into(),
        );
    }
    let data = array
        .as_slice()
        .map_err(|_| errors::shape(format!("{name} must be C-contiguous")))?;
    Ok((data, shape.to_vec()))
}

fn array_nd<T: numpy::Element>(
    data: Vec<T>,
    shape: &[usize],
) -> PyResult<numpy::ndarray::ArrayD<T>> {
    numpy::ndarray::ArrayD::from_shape_vec(numpy::ndarray::IxDyn(shape), data)
        .map_err(|e| errors::shape(e.to_string()))
}

/// Row offsets (R + 1,) as indices; a negative one is an argument error naming it.
fn offsets_of(offsets: &PyReadonlyArray1<'_, i64>) -> PyResult<Vec<usize>> {
    slice1(offsets, "offsets")?
        .iter()
        .map(|&o| {
            usize::try_from(o)
                .map_err(|_| errors::argument(format!("offsets must be non-negative, got {o}")))
        })
        .collect()
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    parse::register(m)?;
    kinematics::register(m)?;
    metrics::register(m)?;
    stats::register(m)?;
    safety::register(m)?;
    intent::register(m)?;
    objects::register(m)?;
    planning_sim::register(m)?;
    planning_scores::register(m)?;
    m.add("STEP_SECONDS", definitions::STEP_SECONDS)?;
    m.add("EGO_LENGTH", definitions::EGO_LENGTH)?;
    m.add("EGO_WIDTH", definitions::EGO_WIDTH)?;
    m.add("EGO_OFFSET", definitions::EGO_OFFSET)?;
    m.add("MIN_STEP", definitions::MIN_STEP)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
