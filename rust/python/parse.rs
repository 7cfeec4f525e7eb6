//! `parse_actions`: a batch of stage-3 answers → actions, status and failure codes, reasons ([`crate::parse`]).

use numpy::ndarray::Array1;
use numpy::{IntoPyArray, PyArray1, PyArray3, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyList;

use super::{frames_view, maybe_detach, shape_to_3d, texts_of};
use crate::error::CoreError;
use crate::parse;

/// What `parse_actions` returns: actions, status codes, failure codes, reasons.
type ParsedBatch<'py> = (
    Bound<'py, PyArray3<f64>>,
    Bound<'py, PyArray1<u8>>,
    Bound<'py, PyArray1<u8>>,
    Vec<String>,
);

/// parse_actions(texts, n, mode, speed_range, max_abs_curvature, history)
///     -> (actions (N, n, 2), status codes (N,), failure codes (N,), reasons)
///
/// `history`: None, or a C-contiguous float64 (N, n, 2) array of the histories the
/// prompts printed (a lenient candidate equal to its row is a quotation).
#[pyfunction]
#[pyo3(signature = (texts, n = 6, mode = "lenient", speed_range = Some((-10.0, 50.0)), max_abs_curvature = Some(1.0), history = None))]
fn parse_actions<'py>(
    py: Python<'py>,
    texts: &Bound<'py, PyList>,
    n: usize,
    mode: &str,
    speed_range: Option<(f64, f64)>,
    max_abs_curvature: Option<f64>,
    history: Option<PyReadonlyArrayDyn<'py, f64>>,
) -> PyResult<ParsedBatch<'py>> {
    let mode = parse::Mode::from_name(mode)?;
    let limits = parse::Limits::new(speed_range, max_abs_curvature)?;
    let texts = texts_of(texts)?;
    let count = texts.len();
    let history_view = match &history {
        None => None,
        Some(h) => {
            let (data, rows, steps) = frames_view(h, "history")?;
            if rows != count || steps != n {
                return Err(CoreError::Shape(format!(
                    "history must have shape ({count}, {n}, 2) like the texts, got {:?}",
                    h.shape()
                ))
                .into());
            }
            Some(data)
        }
    };
    let (values, status, failure, reasons) = maybe_detach(py, count, || {
        parse::parse_batch(&texts, n, mode, &limits, history_view)
    })?;
    let values = shape_to_3d(values, count, n)?;
    Ok((
        values.into_pyarray(py),
        Array1::from(status).into_pyarray(py),
        Array1::from(failure).into_pyarray(py),
        reasons,
    ))
}

/// Add `parse_actions` and the parser's names (`PARSE_MODES`, `PARSE_FAILURES`, `PARSE_STATUSES`) to `_core`.
pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(parse_actions, m)?)?;
    m.add("PARSE_MODES", parse::Mode::NAMES.to_vec())?;
    m.add("PARSE_FAILURES", parse::Failure::NAMES.to_vec())?;
    m.add("PARSE_STATUSES", parse::Status::NAMES.to_vec())?;
    Ok(())
}
