//! The Python binding `lightemma._core`: thin wrappers that borrow NumPy arrays,
//! release the GIL for large batches and return NumPy arrays. All errors become
//! `ValueError` here, in one place.

use numpy::ndarray::{Array1, Array2, Array3};
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1,
    PyReadonlyArrayDyn, PyUntypedArrayMethods,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::pybacked::PyBackedStr;
use pyo3::types::{PyList, PyString};

use crate::error::CoreError;
use crate::{kinematics, metrics, parse, safety, stats};

mod intent;
mod planning_scores;
mod planning_sim;

/// Batches at least this large run with the GIL released.
const DETACH_MIN_FRAMES: usize = 2048;

impl From<CoreError> for PyErr {
    fn from(err: CoreError) -> PyErr {
        PyValueError::new_err(err.to_string())
    }
}

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
        .map_err(|_| PyValueError::new_err(format!("{name} must be C-contiguous")))?;
    Ok((data, shape[0], shape[1]))
}

fn shape_to_3d(data: Vec<f64>, n: usize, t: usize) -> PyResult<Array3<f64>> {
    Array3::from_shape_vec((n, t, 2), data).map_err(|e| PyValueError::new_err(e.to_string()))
}

/// What `parse_actions` returns: actions, status codes, failure codes, reasons.
type ParsedBatch<'py> = (
    Bound<'py, PyArray3<f64>>,
    Bound<'py, PyArray1<u8>>,
    Bound<'py, PyArray1<u8>>,
    Vec<String>,
);

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
            PyValueError::new_err(format!("texts must be str: item {i} is {type_name}"))
        })?;
        texts.push(match PyBackedStr::try_from(s.clone()) {
            Ok(backed) => Text::Backed(backed),
            Err(_) => Text::Lossy(s.to_string_lossy().into_owned()),
        });
    }
    Ok(texts)
}

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
                PyValueError::new_err(
                    "out must be writeable and must not share memory with actions",
                )
            })?;
            let slice = write
                .as_slice_mut()
                .map_err(|_| PyValueError::new_err("out must be C-contiguous"))?;
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
    let out =
        Array2::from_shape_vec((n, t), out).map_err(|e| PyValueError::new_err(e.to_string()))?;
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
                .map_err(|_| PyValueError::new_err("mask must be C-contiguous"))
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
                .map_err(|_| PyValueError::new_err("mask must be C-contiguous"))
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
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(out.into_pyarray(py))
}

/// Borrow a C-contiguous 1-D array.
fn slice1<'a, T: numpy::Element>(
    array: &'a PyReadonlyArray1<'_, T>,
    name: &str,
) -> PyResult<&'a [T]> {
    array
        .as_slice()
        .map_err(|_| PyValueError::new_err(format!("{name} must be C-contiguous")))
}

/// Cluster sums (K, M), counts (K,) and row offsets (R + 1,) as a `stats::Clusters`.
fn clusters_view<'a>(
    sums: &'a PyReadonlyArrayDyn<'_, f64>,
    counts: &'a PyReadonlyArray1<'_, f64>,
    offsets: &'a [usize],
) -> PyResult<stats::Clusters<'a>> {
    let shape = sums.shape();
    if shape.len() != 2 {
        return Err(CoreError::Shape(format!(
            "sums must have shape (clusters, metrics), got {shape:?}"
        ))
        .into());
    }
    let data = sums
        .as_slice()
        .map_err(|_| PyValueError::new_err("sums must be C-contiguous"))?;
    Ok(stats::Clusters {
        sums: data,
        counts: slice1(counts, "counts")?,
        offsets,
        metrics: shape[1],
    })
}

fn offsets_of(offsets: &PyReadonlyArray1<'_, i64>) -> PyResult<Vec<usize>> {
    slice1(offsets, "offsets")?
        .iter()
        .map(|&o| {
            usize::try_from(o).map_err(|_| {
                PyValueError::new_err(format!("offsets must be non-negative, got {o}"))
            })
        })
        .collect()
}

/// cluster_bootstrap(sums (K, M), counts (K,), offsets (R+1,), streams (R,), n_resamples, seed, confidence)
/// -> (R, M, 2) percentile intervals of Σ sums / Σ counts over clusters drawn with replacement
#[pyfunction]
#[pyo3(signature = (sums, counts, offsets, streams, n_resamples = 10_000, seed = 0, confidence = 0.95))]
#[allow(clippy::too_many_arguments)]
fn cluster_bootstrap<'py>(
    py: Python<'py>,
    sums: PyReadonlyArrayDyn<'py, f64>,
    counts: PyReadonlyArray1<'py, f64>,
    offsets: PyReadonlyArray1<'py, i64>,
    streams: PyReadonlyArray1<'py, u64>,
    n_resamples: usize,
    seed: u64,
    confidence: f64,
) -> PyResult<Bound<'py, PyArray3<f64>>> {
    let offsets = offsets_of(&offsets)?;
    let clusters = clusters_view(&sums, &counts, &offsets)?;
    let streams = slice1(&streams, "streams")?;
    let out =
        py.detach(|| stats::cluster_bootstrap(&clusters, streams, n_resamples, seed, confidence))?;
    let shape = (clusters.rows(), clusters.metrics, 2);
    Ok(Array3::from_shape_vec(shape, out)
        .map_err(|e| PyValueError::new_err(e.to_string()))?
        .into_pyarray(py))
}

/// sign_flip_test(sums (K, 1), counts (K,), offsets (R+1,), streams (R,), n_permutations, seed) -> p-values (R,)
#[pyfunction]
#[pyo3(signature = (sums, counts, offsets, streams, n_permutations = 10_000, seed = 0))]
fn sign_flip_test<'py>(
    py: Python<'py>,
    sums: PyReadonlyArrayDyn<'py, f64>,
    counts: PyReadonlyArray1<'py, f64>,
    offsets: PyReadonlyArray1<'py, i64>,
    streams: PyReadonlyArray1<'py, u64>,
    n_permutations: usize,
    seed: u64,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let offsets = offsets_of(&offsets)?;
    let clusters = clusters_view(&sums, &counts, &offsets)?;
    let streams = slice1(&streams, "streams")?;
    let out = py.detach(|| stats::sign_flip_pvalues(&clusters, streams, n_permutations, seed))?;
    Ok(Array1::from(out).into_pyarray(py))
}

// ---- safety geometry (rust/safety.rs) ----

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
        .map_err(|_| PyValueError::new_err(format!("{name} must be C-contiguous")))?;
    Ok((data, shape.to_vec()))
}

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

fn array_nd<T: numpy::Element>(
    data: Vec<T>,
    shape: &[usize],
) -> PyResult<numpy::ndarray::ArrayD<T>> {
    numpy::ndarray::ArrayD::from_shape_vec(numpy::ndarray::IxDyn(shape), data)
        .map_err(|e| PyValueError::new_err(e.to_string()))
}

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
#[pyo3(signature = (traj, poses, length = 4.084, width = 1.85, offset = 0.0, min_step = 1.0))]
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
#[pyo3(signature = (traj, poses, length = 4.084, width = 1.85, offset = 0.0, min_step = 1.0))]
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
#[pyo3(signature = (traj, poses, agents, length = 4.084, width = 1.85, offset = 0.0, min_step = 1.0))]
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

fn mask_of<'a>(
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
#[pyo3(signature = (traj, poses, mask, resolution = 0.1, foreground = 255, length = 4.084, width = 1.85, offset = 0.0, min_step = 1.0))]
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
#[pyo3(signature = (traj, poses, xy, rings, polygons, length = 4.084, width = 1.85, offset = 0.0, min_step = 1.0))]
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

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(parse_actions, m)?)?;
    m.add_function(wrap_pyfunction!(integrate, m)?)?;
    m.add_function(wrap_pyfunction!(displacement_errors, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate_all, m)?)?;
    m.add_function(wrap_pyfunction!(frame_metrics, m)?)?;
    m.add_function(wrap_pyfunction!(cluster_bootstrap, m)?)?;
    m.add_function(wrap_pyfunction!(sign_flip_test, m)?)?;
    m.add_function(wrap_pyfunction!(ego_poses, m)?)?;
    m.add_function(wrap_pyfunction!(footprint_corners, m)?)?;
    m.add_function(wrap_pyfunction!(box_collisions, m)?)?;
    m.add_function(wrap_pyfunction!(mask_area, m)?)?;
    m.add_function(wrap_pyfunction!(polygon_area, m)?)?;
    m.add_function(wrap_pyfunction!(mask_lookup, m)?)?;
    intent::register(m)?;
    planning_sim::register(m)?;
    planning_scores::register(m)?;
    m.add("METHODS", kinematics::Method::NAMES.to_vec())?;
    m.add("CONVENTIONS", metrics::Convention::NAMES.to_vec())?;
    m.add("PARSE_MODES", parse::Mode::NAMES.to_vec())?;
    m.add("PARSE_FAILURES", parse::Failure::NAMES.to_vec())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
