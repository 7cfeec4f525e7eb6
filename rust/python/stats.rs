//! Scene-bootstrap intervals and sign-flip p-values over clusters ([`crate::stats`]).

use numpy::ndarray::{Array1, Array3};
use numpy::{
    IntoPyArray, PyArray1, PyArray3, PyReadonlyArray1, PyReadonlyArrayDyn, PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use super::{errors, offsets_of, slice1};
use crate::error::CoreError;
use crate::stats;

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
        .map_err(|_| errors::shape("sums must be C-contiguous"))?;
    Ok(stats::Clusters {
        sums: data,
        counts: slice1(counts, "counts")?,
        offsets,
        metrics: shape[1],
    })
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
        .map_err(|e| errors::shape(e.to_string()))?
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

/// Add `cluster_bootstrap` and `sign_flip_test` to `_core`.
pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(cluster_bootstrap, m)?)?;
    m.add_function(wrap_pyfunction!(sign_flip_test, m)?)?;
    Ok(())
}
