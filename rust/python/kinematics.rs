//! `integrate`: actions → trajectories ([`crate::kinematics`]).

use numpy::{IntoPyArray, PyArray3, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;

use super::{errors, frames_view, maybe_detach, shape_to_3d};
use crate::error::CoreError;
use crate::kinematics;

/// integrate(actions (N, T, 2), dt, method, out=None) -> positions (N, T, 2)
///
/// `out`: a C-contiguous float64 array of the same shape to write the positions into (returned);
/// at large N this spares allocating, and zero-filling, a new array per call.
#[pyfunction]
#[pyo3(signature = (actions, dt = 0.5, method = "euler", out = None))]
fn integrate<'py>(
    py: Python<'py>,
    actions: PyReadonlyArrayDyn<'py, f64>,
    dt: f64,
    method: &str,
    out: Option<Bound<'py, PyArray3<f64>>>,
) -> PyResult<Bound<'py, PyArray3<f64>>> {
    let method = kinematics::Method::from_name(method)?;
    let (data, n, t) = frames_view(&actions, "actions")?;
    if t == 0 {
        return Err(
            CoreError::Shape("actions must have at least one step (T ≥ 1)".to_owned()).into(),
        );
    }
    if let Some(target) = out {
        if target.shape() != [n, t, 2] {
            return Err(CoreError::Shape(format!(
                "out must have the shape of actions ({n}, {t}, 2), got {:?}",
                target.shape()
            ))
            .into());
        }
        {
            let mut write = target.try_readwrite().map_err(|_| {
                errors::argument("out must be writeable and must not share memory with actions")
            })?;
            let slice = write
                .as_slice_mut()
                .map_err(|_| errors::shape("out must be C-contiguous"))?;
            maybe_detach(py, n, || {
                kinematics::integrate_batch(data, t, dt, method, slice)
            })?;
        }
        return Ok(target);
    }
    let out = maybe_detach(py, n, || {
        let mut out = vec![0.0; data.len()];
        kinematics::integrate_batch(data, t, dt, method, &mut out).map(|()| out)
    })?;
    Ok(shape_to_3d(out, n, t)?.into_pyarray(py))
}

/// Add `integrate` and the integration methods (`METHODS`) to `_core`.
pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(integrate, m)?)?;
    m.add("METHODS", kinematics::Method::NAMES.to_vec())?;
    Ok(())
}
