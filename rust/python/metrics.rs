//! Displacement errors, ADE / FDE under each convention and the miss rate ([`crate::metrics`]).

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray2, PyReadonlyArray1, PyReadonlyArrayDyn};
use pyo3::prelude::*;

use super::{errors, frames_view, maybe_detach};
use crate::error::CoreError;
use crate::metrics;

/// Check that prediction and ground truth are both (N, T, 2) with equal N and T.
fn paired_views<'a>(
    pred: &'a PyReadonlyArrayDyn<'_, f64>,
    gt: &'a PyReadonlyArrayDyn<'_, f64>,
) -> PyResult<(&'a [f64], &'a [f64], usize, usize)> {
    let (p, n, t) = frames_view(pred, "pred")?;
    let (g, gn, gt_steps) = frames_view(gt, "gt")?;
    if (n, t) != (gn, gt_steps) {
        return Err(CoreError::Shape(format!(
            "pred has shape ({n}, {t}, 2) but gt has shape ({gn}, {gt_steps}, 2); they must match"
        ))
        .into());
    }
    Ok((p, g, n, t))
}

/// displacement_errors(pred (N, T, 2), gt (N, T, 2)) -> errors (N, T)
#[pyfunction]
fn displacement_errors<'py>(
    py: Python<'py>,
    pred: PyReadonlyArrayDyn<'py, f64>,
    gt: PyReadonlyArrayDyn<'py, f64>,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let (p, g, n, t) = paired_views(&pred, &gt)?;
    let out = maybe_detach(py, n, || {
        let mut out = vec![0.0; n * t];
        metrics::displacement_errors(p, g, &mut out).map(|()| out)
    })?;
    let out = Array2::from_shape_vec((n, t), out).map_err(|e| errors::shape(e.to_string()))?;
    Ok(out.into_pyarray(py))
}

/// evaluate(pred, gt, convention, miss_threshold, mask) -> (ade_1s, ade_2s, ade_3s, ade_avg, fde, miss_rate, n_frames)
///
/// `mask`: optional C-contiguous bool array (N,); only frames marked true are checked and scored.
#[pyfunction]
#[pyo3(signature = (pred, gt, convention = "lightemma", miss_threshold = 2.0, mask = None))]
fn evaluate(
    py: Python<'_>,
    pred: PyReadonlyArrayDyn<'_, f64>,
    gt: PyReadonlyArrayDyn<'_, f64>,
    convention: &str,
    miss_threshold: f64,
    mask: Option<PyReadonlyArray1<'_, bool>>,
) -> PyResult<(f64, f64, f64, f64, f64, f64, usize)> {
    let convention = metrics::Convention::from_name(convention)?;
    let (p, g, n, t) = paired_views(&pred, &gt)?;
    let mask = mask
        .as_ref()
        .map(|m| {
            m.as_slice()
                .map_err(|_| errors::shape("mask must be C-contiguous"))
        })
        .transpose()?;
    let s = maybe_detach(py, n, || {
        metrics::evaluate_masked(p, g, mask, t, convention, miss_threshold)
    })?;
    Ok((
        s.ade_1s,
        s.ade_2s,
        s.ade_3s,
        s.ade_avg,
        s.fde,
        s.miss_rate,
        s.n_frames,
    ))
}

/// evaluate_all(pred, gt, miss_threshold, mask) -> one evaluate() tuple per convention, in CONVENTIONS order
///
/// One error matrix for all three conventions: the same numbers as three evaluate() calls.
#[pyfunction]
#[pyo3(signature = (pred, gt, miss_threshold = 2.0, mask = None))]
#[allow(clippy::type_complexity)]
fn evaluate_all(
    py: Python<'_>,
    pred: PyReadonlyArrayDyn<'_, f64>,
    gt: PyReadonlyArrayDyn<'_, f64>,
    miss_threshold: f64,
    mask: Option<PyReadonlyArray1<'_, bool>>,
) -> PyResult<Vec<(f64, f64, f64, f64, f64, f64, usize)>> {
    let (p, g, n, t) = paired_views(&pred, &gt)?;
    let mask = mask
        .as_ref()
        .map(|m| {
            m.as_slice()
                .map_err(|_| errors::shape("mask must be C-contiguous"))
        })
        .transpose()?;
    let all = maybe_detach(py, n, || {
        metrics::evaluate_all(p, g, mask, t, miss_threshold)
    })?;
    Ok(all
        .iter()
        .map(|s| {
            (
                s.ade_1s,
                s.ade_2s,
                s.ade_3s,
                s.ade_avg,
                s.fde,
                s.miss_rate,
                s.n_frames,
            )
        })
        .collect())
}

/// frame_metrics(pred, gt, convention) -> (N, 5): ADE 1s, 2s, 3s, ADE avg, FDE per frame
#[pyfunction]
#[pyo3(signature = (pred, gt, convention = "lightemma"))]
fn frame_metrics<'py>(
    py: Python<'py>,
    pred: PyReadonlyArrayDyn<'py, f64>,
    gt: PyReadonlyArrayDyn<'py, f64>,
    convention: &str,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let convention = metrics::Convention::from_name(convention)?;
    let (p, g, n, t) = paired_views(&pred, &gt)?;
    let out = maybe_detach(py, n, || {
        let mut out = vec![0.0; n * metrics::FRAME_VALUES];
        metrics::frame_metrics(p, g, t, convention, &mut out).map(|()| out)
    })?;
    let out = Array2::from_shape_vec((n, metrics::FRAME_VALUES), out)
        .map_err(|e| errors::shape(e.to_string()))?;
    Ok(out.into_pyarray(py))
}

/// Add the metric kernels and the conventions (`CONVENTIONS`) to `_core`.
pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(displacement_errors, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate_all, m)?)?;
    m.add_function(wrap_pyfunction!(frame_metrics, m)?)?;
    m.add("CONVENTIONS", metrics::Convention::NAMES.to_vec())?;
    Ok(())
}
