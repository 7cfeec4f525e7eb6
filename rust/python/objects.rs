//! Binding of the scene-description object reader (`rust/objects.rs`, rules `objects@lightemma/1`).
//! A list of str in; mention codes (N, C) u8 and counts (N, C) i32 as NumPy arrays, reasons as a
//! list. The GIL is released for large batches.

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray2};
use pyo3::prelude::*;
use pyo3::types::PyList;

use super::{maybe_detach, texts_of, Text};
use crate::objects as reader;

/// What `read_objects` returns: mention codes (N, C), counts (N, C), reasons.
type ObjectBatch<'py> = (
    Bound<'py, PyArray2<u8>>,
    Bound<'py, PyArray2<i32>>,
    Vec<String>,
);

/// read_objects(texts) -> (mention codes (N, C) u8, counts (N, C) i32, reasons); C = len(OBJECT_CLASSES),
///     codes 0 not mentioned, 1 affirmed, 2 negated, 3 hedged, 255 unknown; count -1 where none is stated.
#[pyfunction]
fn read_objects<'py>(py: Python<'py>, texts: &Bound<'py, PyList>) -> PyResult<ObjectBatch<'py>> {
    let texts = texts_of(texts)?;
    let lossy: Vec<bool> = texts.iter().map(|t| matches!(t, Text::Lossy(_))).collect();
    let out = maybe_detach(py, texts.len(), || reader::read_batch(&texts, &lossy));
    let c = reader::CLASSES.len();
    let mut mentions = Vec::with_capacity(out.len() * c);
    let mut counts = Vec::with_capacity(out.len() * c);
    let mut reasons = Vec::with_capacity(out.len());
    for o in out {
        mentions.extend_from_slice(&o.mentions);
        counts.extend_from_slice(&o.counts);
        reasons.push(o.reason);
    }
    let n = reasons.len();
    let shape = |e: numpy::ndarray::ShapeError| super::errors::shape(e.to_string());
    Ok((
        Array2::from_shape_vec((n, c), mentions)
            .map_err(shape)?
            .into_pyarray(py),
        Array2::from_shape_vec((n, c), counts)
            .map_err(shape)?
            .into_pyarray(py),
        reasons,
    ))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(read_objects, m)?)?;
    m.add("OBJECT_RULES", reader::RULES)?;
    m.add("OBJECT_CLASSES", reader::CLASSES.to_vec())?;
    m.add("OBJECT_MENTIONS", reader::MENTIONS.to_vec())?;
    m.add("OBJECT_UNKNOWN", reader::UNKNOWN)?;
    Ok(())
}
