//! Binding of the stage-2 intent reader (`rust/intent.rs`, rules `intent@lightemma/1`). A list of
//! str in; class codes as NumPy arrays, reasons and sentences as lists. The GIL is released for
//! large batches.

use numpy::ndarray::Array1;
use numpy::{IntoPyArray, PyArray1};
use pyo3::prelude::*;
use pyo3::types::PyList;

use super::{maybe_detach, texts_of, Text};
use crate::intent as reader;

/// What `read_intents` returns: longitudinal codes (N,), lateral codes (N,), reasons,
/// longitudinal sentences, lateral sentences.
type IntentBatch<'py> = (
    Bound<'py, PyArray1<u8>>,
    Bound<'py, PyArray1<u8>>,
    Vec<String>,
    Vec<String>,
    Vec<String>,
);

/// read_intents(texts) -> (longitudinal codes (N,) u8, lateral codes (N,) u8, reasons,
///     longitudinal sentences, lateral sentences); code 255 is unknown.
#[pyfunction]
fn read_intents<'py>(py: Python<'py>, texts: &Bound<'py, PyList>) -> PyResult<IntentBatch<'py>> {
    let texts = texts_of(texts)?;
    let lossy: Vec<bool> = texts.iter().map(|t| matches!(t, Text::Lossy(_))).collect();
    let out = maybe_detach(py, texts.len(), || reader::read_batch(&texts, &lossy));
    let mut lon = Vec::with_capacity(out.len());
    let mut lat = Vec::with_capacity(out.len());
    let mut reasons = Vec::with_capacity(out.len());
    let mut lon_s = Vec::with_capacity(out.len());
    let mut lat_s = Vec::with_capacity(out.len());
    for i in out {
        lon.push(i.longitudinal);
        lat.push(i.lateral);
        reasons.push(i.reason);
        lon_s.push(i.longitudinal_sentence);
        lat_s.push(i.lateral_sentence);
    }
    Ok((
        Array1::from(lon).into_pyarray(py),
        Array1::from(lat).into_pyarray(py),
        reasons,
        lon_s,
        lat_s,
    ))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(read_intents, m)?)?;
    m.add("INTENT_RULES", reader::RULES)?;
    m.add("INTENT_LONGITUDINAL", reader::LONGITUDINAL.to_vec())?;
    m.add("INTENT_LATERAL", reader::LATERAL.to_vec())?;
    m.add("INTENT_UNKNOWN", reader::UNKNOWN)?;
    m.add("INTENT_MAX_BYTES", reader::MAX_BYTES)?;
    Ok(())
}
