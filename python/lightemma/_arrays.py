"""Turning user input into the C-contiguous float64 arrays the Rust core borrows."""

from __future__ import annotations

from typing import Any

import numpy as np


def as_frames(value: Any, name: str) -> tuple[np.ndarray, bool]:
    """``value`` as a C-contiguous float64 array of shape (N, T, 2).

    A single frame of shape (T, 2) is accepted and reported with ``single=True``
    so that callers can return the same rank they were given. No copy is made
    when the input already is a C-contiguous float64 array.
    """
    try:
        array = np.asarray(value)
    except Exception as exc:  # ragged lists and the like
        raise ValueError(f"{name} cannot be turned into an array: {exc}") from None
    if array.dtype == object or not (np.issubdtype(array.dtype, np.number) or array.dtype == np.bool_):
        raise ValueError(f"{name} must hold numbers, got dtype {array.dtype} (shape {array.shape})")
    if np.issubdtype(array.dtype, np.complexfloating):
        raise ValueError(f"{name} must hold real numbers, got dtype {array.dtype}")
    single = array.ndim == 2
    if single:
        array = array[np.newaxis]
    if array.ndim != 3 or array.shape[2] != 2:
        shown = array.shape[1:] if single else array.shape
        raise ValueError(f"{name} must have shape (N, T, 2) or (T, 2), got {shown}")
    return np.ascontiguousarray(array, dtype=np.float64), single
