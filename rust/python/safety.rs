//! Safety geometry: ego footprints, box collisions, drivable-area lookups ([`crate::safety`]).

use numpy::ndarray::Array1;
use numpy::{IntoPyArray, PyArray1, PyReadonlyArray1, PyReadonlyArrayDyn};
use pyo3::prelude::*;

use super::{array_nd, frames_view, offsets_of, view_nd};
use crate::error::CoreError;
use crate::safety;

/// Trajectories (N, T, 2) and poses (N, 3) checked against each other; returns (traj, poses, N, T).
fn safety_inputs<'a>(
    traj: &'a PyReadonlyArrayDyn<'_, f64>,
    poses: &'a PyReadonlyArrayDyn<'_, f64>,
) -> PyResult<(&'a [f64], &'a [f64], usize, usize)> {
    let (t, n, steps) = frames_view(traj, "trajectories")?;
    let (p, ps) = view_nd(poses, "poses", 2, &[3], "(N, 3)")?;
    if ps[0] != n {
        return Err(CoreError::Shape(format!(
            "poses has {} rows but trajectories has {n} frames",
            ps[0]
        ))
        .into());
    }
    Ok((t, p, n, steps))
}

/// The ego box of a safety kernel call. Every kernel's defaults are lightemma's ego box
/// ([`crate::definitions::EGO_LENGTH`], [`crate::definitions::EGO_WIDTH`], [`crate::definitions::EGO_OFFSET`],
/// [`crate::definitions::MIN_STEP`]), written as literals so that Python's signatures show them;
/// tests/unit/package/test_definitions.py checks each against the constants.
fn ego_shape(length: f64, width: f64, offset: f64, min_step: f64) -> PyResult<safety::EgoShape> {
    let shape = safety::EgoShape {
        length,
        width,
        offset,
        min_step,
    };
    shape.check()?;
    Ok(shape)
}

/// ego_poses(traj (N, T, 2), poses (N, 3), length, width, offset, min_step) -> (N, T, 3) global x, y, heading
#[pyfunction]
#[pyo3(signature = (traj, poses, length = 4.084, width = 1.85, offset = 1.443713, min_step = 1.0))]
fn ego_poses<'py>(
    py: Python<'py>,
    traj: PyReadonlyArrayDyn<'py, f64>,
    poses: PyReadonlyArrayDyn<'py, f64>,
    length: f64,
    width: f64,
    offset: f64,
    min_step: f64,
) -> PyResult<Bound<'py, numpy::PyArrayDyn<f64>>> {
    let shape = ego_shape(length, width, offset, min_step)?;
    let (t, p, n, steps) = safety_inputs(&traj, &poses)?;
    let out = py.detach(|| safety::global_poses(t, p, steps, &shape))?;
    Ok(array_nd(out, &[n, steps, 3])?.into_pyarray(py))
}

/// footprint_corners(traj, poses, length, width, offset, min_step) -> (N, T, 4, 2)
#[pyfunction]
#[pyo3(signature = (traj, poses, length = 4.084, width = 1.85, offset = 1.443713, min_step = 1.0))]
fn footprint_corners<'py>(
    py: Python<'py>,
    traj: PyReadonlyArrayDyn<'py, f64>,
    poses: PyReadonlyArrayDyn<'py, f64>,
    length: f64,
    width: f64,
    offset: f64,
    min_step: f64,
) -> PyResult<Bound<'py, numpy::PyArrayDyn<f64>>> {
    let shape = ego_shape(length, width, offset, min_step)?;
    let (t, p, n, steps) = safety_inputs(&traj, &poses)?;
    let out = py.detach(|| safety::footprint_corners(t, p, steps, &shape))?;
    Ok(array_nd(out, &[n, steps, 4, 2])?.into_pyarray(py))
}

/// box_collisions(traj, poses, agents (N, T, A, 5), length, width, offset, min_step) -> (N, T, A) bool
#[pyfunction]
#[pyo3(signature = (traj, poses, agents, length = 4.084, width = 1.85, offset = 1.443713, min_step = 1.0))]
#[allow(clippy::too_many_arguments)]
fn box_collisions<'py>(
    py: Python<'py>,
    traj: PyReadonlyArrayDyn<'py, f64>,
    poses: PyReadonlyArrayDyn<'py, f64>,
    agents: PyReadonlyArrayDyn<'py, f64>,
    length: f64,
    width: f64,
    offset: f64,
    min_step: f64,
) -> PyResult<Bound<'py, numpy::PyArrayDyn<bool>>> {
    let shape = ego_shape(length, width, offset, min_step)?;
    let (t, p, n, steps) = safety_inputs(&traj, &poses)?;
    let (a, ashape) = view_nd(&agents, "agents", 4, &[safety::BOX_VALUES], "(N, T, A, 5)")?;
    if ashape[0] != n || ashape[1] != steps {
        return Err(CoreError::Shape(format!(
            "agents has shape {ashape:?} but trajectories are ({n}, {steps}, 2)"
        ))
        .into());
    }
    let slots = ashape[2];
    let out = py.detach(|| safety::collisions(t, p, a, steps, slots, &shape))?;
    let out: Vec<bool> = out.into_iter().map(|v| v != 0).collect();
    Ok(array_nd(out, &[n, steps, slots])?.into_pyarray(py))
}

pub(super) fn mask_of<'a>(
    mask: &'a PyReadonlyArrayDyn<'_, u8>,
    resolution: f64,
    foreground: u8,
) -> PyResult<safety::Mask<'a>> {
    let (data, shape) = view_nd(mask, "mask", 2, &[], "(H, W)")?;
    let m = safety::Mask {
        data,
        height: shape[0],
        width: shape[1],
        resolution,
        foreground,
    };
    m.check()?;
    Ok(m)
}

/// mask_area(traj, poses, mask (H, W) uint8, resolution, foreground, length, width, offset, min_step)
/// -> (N, T, 5) uint8: 0 off, 1 on, 2 outside the image, for the 4 corners and the reference point
#[pyfunction]
#[pyo3(signature = (traj, poses, mask, resolution = 0.1, foreground = 255, length = 4.084, width = 1.85, offset = 1.443713, min_step = 1.0))]
#[allow(clippy::too_many_arguments)]
fn mask_area<'py>(
    py: Python<'py>,
    traj: PyReadonlyArrayDyn<'py, f64>,
    poses: PyReadonlyArrayDyn<'py, f64>,
    mask: PyReadonlyArrayDyn<'py, u8>,
    resolution: f64,
    foreground: u8,
    length: f64,
    width: f64,
    offset: f64,
    min_step: f64,
) -> PyResult<Bound<'py, numpy::PyArrayDyn<u8>>> {
    let shape = ego_shape(length, width, offset, min_step)?;
    let (t, p, n, steps) = safety_inputs(&traj, &poses)?;
    let area = safety::Area::Mask(mask_of(&mask, resolution, foreground)?);
    let out = py.detach(|| safety::footprint_area(t, p, steps, &shape, &area))?;
    Ok(array_nd(out, &[n, steps, safety::TEST_POINTS])?.into_pyarray(py))
}

/// polygon_area(traj, poses, xy (V, 2), rings (R+1,), polygons (P+1,), length, width, offset, min_step)
/// -> (N, T, 5) uint8: 0 off, 1 on, for the 4 corners and the reference point
#[pyfunction]
#[pyo3(signature = (traj, poses, xy, rings, polygons, length = 4.084, width = 1.85, offset = 1.443713, min_step = 1.0))]
#[allow(clippy::too_many_arguments)]
fn polygon_area<'py>(
    py: Python<'py>,
    traj: PyReadonlyArrayDyn<'py, f64>,
    poses: PyReadonlyArrayDyn<'py, f64>,
    xy: PyReadonlyArrayDyn<'py, f64>,
    rings: PyReadonlyArray1<'py, i64>,
    polygons: PyReadonlyArray1<'py, i64>,
    length: f64,
    width: f64,
    offset: f64,
    min_step: f64,
) -> PyResult<Bound<'py, numpy::PyArrayDyn<u8>>> {
    let shape = ego_shape(length, width, offset, min_step)?;
    let (t, p, n, steps) = safety_inputs(&traj, &poses)?;
    let (xy, _) = view_nd(&xy, "xy", 2, &[2], "(V, 2)")?;
    let rings = offsets_of(&rings)?;
    let polygons = offsets_of(&polygons)?;
    let index = safety::PolygonIndex::new(safety::Polygons {
        xy,
        rings: &rings,
        polygons: &polygons,
    })?;
    let area = safety::Area::Polygons(index);
    let out = py.detach(|| safety::footprint_area(t, p, steps, &shape, &area))?;
    Ok(array_nd(out, &[n, steps, safety::TEST_POINTS])?.into_pyarray(py))
}

/// mask_lookup(points (M, 2), mask (H, W) uint8, resolution, foreground) -> (M,) uint8 (0 off, 1 on, 2 outside)
#[pyfunction]
#[pyo3(signature = (points, mask, resolution = 0.1, foreground = 255))]
fn mask_lookup<'py>(
    py: Python<'py>,
    points: PyReadonlyArrayDyn<'py, f64>,
    mask: PyReadonlyArrayDyn<'py, u8>,
    resolution: f64,
    foreground: u8,
) -> PyResult<Bound<'py, PyArray1<u8>>> {
    let (pts, _) = view_nd(&points, "points", 2, &[2], "(M, 2)")?;
    let m = mask_of(&mask, resolution, foreground)?;
    let out = py.detach(|| safety::mask_points(pts, &m))?;
    Ok(Array1::from(out).into_pyarray(py))
}

/// Add the safety kernels to `_core`.
pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(ego_poses, m)?)?;
    m.add_function(wrap_pyfunction!(footprint_corners, m)?)?;
    m.add_function(wrap_pyfunction!(box_collisions, m)?)?;
    m.add_function(wrap_pyfunction!(mask_area, m)?)?;
    m.add_function(wrap_pyfunction!(polygon_area, m)?)?;
    m.add_function(wrap_pyfunction!(mask_lookup, m)?)?;
    Ok(())
}
