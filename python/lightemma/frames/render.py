"""Rendering history actions for prompts (docs/definitions.md#frames-and-windows, #the-three-stages).

``{history}``: pairs of plain decimals (``4.512``), never a library repr such
as ``np.float64(4.512)`` and never in exponent notation; ``-0.0`` is written
``0.0``. ``{speeds}`` / ``{curvatures}``: the two lists as the LightEMMA
reference scripts printed them, Python's own ``repr`` of a list of floats
(``[1.299, 1.845, 2.68]``, ``-0.0`` kept).

A history given in float32 (or float16) is written with the shortest decimal that round-trips in its own
precision: ``np.float32(4.512)`` is ``4.512``, not ``4.51200008392334``, the float64 it widens to.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from decimal import Decimal
from typing import Any

import numpy as np

from lightemma.errors import InputError, ShapeError


def format_number(x: float) -> str:
    """Shortest plain decimal that round-trips ``x``: ``4.512``, ``0.0``, ``12.0``, ``0.00001``.

    ``-0.0`` becomes ``0.0``; NaN and infinities raise ``ValueError`` (they have
    no place in a prompt).
    """
    try:
        value = float(x)
    except (TypeError, ValueError) as exc:
        raise InputError(f"cannot render {x!r} as a number") from exc
    if not math.isfinite(value):
        raise InputError(f"cannot render non-finite number {value!r} in a prompt")
    if value == 0.0:
        return "0.0"
    text = repr(value)
    if "e" in text or "E" in text:
        # exponent notation: expand repr's shortest round-tripping digits exactly
        text = format(Decimal(text), "f")
        if "." not in text:
            text += ".0"
    return text


def _narrow_float(value: Any, dtype: np.dtype | None = None) -> Any:
    """A float32 / float16 value (a NumPy scalar, or a Python float read from an array of ``dtype``) as the Python
    float of its shortest round-tripping decimal in that precision (``np.float32(4.512)`` → ``4.512``); any other
    value unchanged."""
    if isinstance(value, np.floating) and value.dtype.itemsize < 8:
        return float(str(value))
    if dtype is not None and isinstance(value, float):
        return float(str(dtype.type(value)))
    return value


def _rows(actions: np.ndarray | Sequence[Sequence[float]]) -> list[Any]:
    """``actions`` as nested Python lists, float32 / float16 values narrowed by :func:`_narrow_float`."""
    if isinstance(actions, np.ndarray):
        narrow = actions.dtype if actions.dtype.kind == "f" and actions.dtype.itemsize < 8 else None
        rows = actions.tolist()
    else:
        narrow, rows = None, [list(row) if isinstance(row, (Sequence, np.ndarray)) else row for row in actions]
    return [
        [_narrow_float(v, narrow) for v in row] if isinstance(row, list) else _narrow_float(row, narrow) for row in rows
    ]


def format_history(actions: np.ndarray | Sequence[Sequence[float]]) -> str:
    """Render (speed, curvature) actions as ``[(4.512, 0.0), (4.6, -0.012), ...]``.

    ``actions`` has shape ``(T, 2)``; the order is kept (most recent last). Float32 / float16 values are written
    as the shortest decimal that round-trips in their own precision (see the module docstring).
    """
    arr = np.asarray(_rows(actions), dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ShapeError(f"history actions must have shape (T, 2), got {arr.shape}")
    pairs = (f"({format_number(v)}, {format_number(c)})" for v, c in arr.tolist())
    return "[" + ", ".join(pairs) + "]"


def format_python_list(values: np.ndarray | Sequence[float]) -> str:
    """``values`` as Python prints a list of them: ``[1.299, -0.0, 0.012]`` (``repr`` of each number).

    This is how the reference scripts put the history speeds and curvatures into
    their prompts (``f"{prev_speed}"``): shortest round-tripping decimals,
    ``-0.0`` kept, exponents for very small or large values (``1e-05``). NumPy
    numbers are written as Python's (never ``np.float64(…)``); a Python ``int``
    stays an ``int`` (the reference wrote a degenerate curvature as ``0``).
    NaN and infinities raise ``ValueError``.
    """
    items = values.tolist() if isinstance(values, np.ndarray) else list(values)
    out = []
    for value in items:
        if isinstance(value, np.generic):
            value = value.item()
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError(f"cannot render {value!r} as a number")
        if isinstance(value, float) and not math.isfinite(value):
            raise InputError(f"cannot render non-finite number {value!r} in a prompt")
        out.append(repr(value))
    return "[" + ", ".join(out) + "]"


def history_placeholders(actions: np.ndarray | Sequence[Sequence[float]]) -> dict[str, str]:
    """The prompt placeholders of a frame's history actions (T, 2): ``history``, ``speeds``, ``curvatures``."""
    rows = _rows(actions)
    if any(not isinstance(row, list) or len(row) != 2 for row in rows):
        raise ShapeError(
            f"history actions must have shape (T, 2), got rows of length "
            f"{sorted({len(r) if isinstance(r, list) else 0 for r in rows})}"
        )
    return {
        "history": format_history(np.asarray(rows, dtype=np.float64).reshape(-1, 2)),
        "speeds": format_python_list([row[0] for row in rows]),
        "curvatures": format_python_list([row[1] for row in rows]),
    }
