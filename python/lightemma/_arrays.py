"""Turning user input into the C-contiguous float64 arrays the Rust core borrows."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from lightemma.errors import InputError, ShapeError


def as_frames(value: Any, name: str) -> tuple[npt.NDArray[np.float64], bool]:
    """``value`` as a C-contiguous float64 array of shape (N, T, 2).

    A single frame of shape (T, 2) is accepted and reported with ``single=True``
    so that callers can return the same rank they were given. No copy is made
    when the input already is a C-contiguous float64 array.
    """
    try:
        array = np.asarray(value)
    except Exception as exc:  # ragged lists and the like
        raise InputError(f"{name} cannot be turned into an array: {exc}") from None
    if array.dtype == object or not np.issubdtype(array.dtype, np.number):  # bool is not a number here
        raise InputError(f"{name} must hold numbers, got dtype {array.dtype} (shape {array.shape})")
    if np.issubdtype(array.dtype, np.complexfloating):
        raise InputError(f"{name} must hold real numbers, got dtype {array.dtype}")
    single = array.ndim == 2
    if single:
        array = array[np.newaxis]
    if array.ndim != 3 or array.shape[2] != 2:
        shown = array.shape[1:] if single else array.shape
        raise ShapeError(f"{name} must have shape (N, T, 2) or (T, 2), got {shown}")
    return np.ascontiguousarray(array, dtype=np.float64), single


def as_mask(value: Any, n: int, single: bool) -> npt.NDArray[np.bool_]:
    """``value`` as a C-contiguous bool array (N,): one entry per frame, ``True`` = use the frame.

    Only real booleans are accepted (0/1 integers would read as indices elsewhere in
    NumPy); a single frame takes a scalar or a one-entry mask.
    """
    array = np.asarray(value)
    if array.dtype != np.bool_:
        raise InputError(f"mask must be a boolean array, got dtype {array.dtype} (shape {array.shape})")
    if single and array.ndim == 0:
        array = array.reshape(1)
    if array.shape != (n,):
        raise ShapeError(f"mask must have shape ({n},), one entry per frame, got {array.shape}")
    return np.ascontiguousarray(array)
