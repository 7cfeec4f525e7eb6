//! The one Rust → Python error mapping (as polars' `PyPolarsErr`): each [`CoreError`] variant becomes one of
//! lightemma's exception classes, defined in Python (`lightemma.errors`, all `ValueError` subclasses, so
//! `except ValueError` keeps catching them) and imported here:
//!
//! | `CoreError`     | Python class                      |
//! |-----------------|-----------------------------------|
//! | `Shape`         | `lightemma.errors.ShapeError`       |
//! | `NonFinite`     | `lightemma.errors.NonFiniteError`   |
//! | `UnknownName`   | `lightemma.errors.UnknownNameError` |
//! | `Argument`      | `lightemma.errors.InputError`       |
//!
//! The binding's own refusals (a non-contiguous array, a non-str text, a negative index) are `CoreError`s
//! too ([`shape`], [`argument`]): no binding raises a Python exception class directly.

use pyo3::prelude::*;

use crate::error::CoreError;

pyo3::import_exception!(lightemma.errors, InputError);
pyo3::import_exception!(lightemma.errors, ShapeError);
pyo3::import_exception!(lightemma.errors, NonFiniteError);
pyo3::import_exception!(lightemma.errors, UnknownNameError);

impl From<CoreError> for PyErr {
    fn from(err: CoreError) -> PyErr {
        let message = err.to_string();
        match err {
            CoreError::Shape(_) => ShapeError::new_err(message),
            CoreError::NonFinite { .. } => NonFiniteError::new_err(message),
            CoreError::UnknownName { .. } => UnknownNameError::new_err(message),
            CoreError::Argument(_) => InputError::new_err(message),
        }
    }
}

/// An array of the wrong shape or memory layout, found by the binding (`lightemma.errors.ShapeError`).
pub(crate) fn shape(message: impl Into<String>) -> PyErr {
    CoreError::Shape(message.into()).into()
}

/// Any other argument the binding refuses (`lightemma.errors.InputError`).
pub(crate) fn argument(message: impl Into<String>) -> PyErr {
    CoreError::Argument(message.into()).into()
}
