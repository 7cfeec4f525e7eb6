"""Parsing a model's stage-3 answer into (speed, curvature) actions.

The rules of each mode, with worked examples, are in ``docs/parsing.md``.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from numbers import Real
from typing import TYPE_CHECKING, TypedDict, cast

import numpy as np
import numpy.typing as npt

from lightemma import _core
from lightemma.definitions import PARSE_FAILURES, PARSE_MODES, STATUSES
from lightemma.errors import InputError, ShapeError

if TYPE_CHECKING:
    from lightemma._core import _ParseMode

DEFAULT_SPEED_RANGE = (-10.0, 50.0)
DEFAULT_MAX_ABS_CURVATURE = 1.0
_STATUS_NAMES = np.array(STATUSES)
_FAILURE_NAMES = np.array(PARSE_FAILURES)


@dataclass(frozen=True)
class ParsedActions:
    """The parse of a batch of answers.

    Attributes:
        actions: float64 array (N, n, 2) of (speed m/s, curvature 1/m); NaN where failed.
        status: array of ``"ok"`` (the strict format, or in paper mode the paper's
            literal rule), ``"corrected"`` (found only by the lenient reading, or by
            the paper's digit-run rule) or ``"failed"``, one per answer.
        reason: one str per answer: ``""`` when plainly ok; otherwise what happened
            (``"skipped 1 list(s) repeating the history given in the prompt"``, ``"expression evaluated"``,
            ``"speed 5254 at step 1 outside [-10, 50] m/s"``, ``"truncated"``, …).
        failure: array of str, one per answer: ``""`` unless failed, else
            ``"truncated"`` (the answer ends inside the list), ``"implausible"``
            (a value outside the plausibility limits), ``"ambiguous"`` (readings
            disagree: several different lists and no cue saying which is final, a
            range ``4.5-5.0`` inside a pair, numbers whose pairing is unknown) or
            ``"format"`` (everything else, including empty answers and non-finite values).
    """

    actions: npt.NDArray[np.float64]
    status: npt.NDArray[np.str_]
    reason: list[str]
    failure: npt.NDArray[np.str_]

    def __len__(self) -> int:
        return len(self.reason)

    @property
    def ok(self) -> npt.NDArray[np.bool_]:
        """Boolean mask of answers whose actions are usable (``ok`` or ``corrected``)."""
        ok: npt.NDArray[np.bool_] = self.status != "failed"
        return ok


def _as_list_of_str(texts: object) -> list[object]:
    """``texts`` as a list for the core, which checks every item is a str."""
    if isinstance(texts, str):
        return [texts]
    if isinstance(texts, np.ndarray):
        if texts.ndim != 1:
            raise ShapeError(f"texts must be a 1-D array of str, got shape {texts.shape}")
        if texts.dtype.kind not in "UO":
            raise InputError(f"texts must be an array of str, got dtype {texts.dtype}")
        items: list[object] = texts.tolist()
        return items
    if isinstance(texts, list):
        return texts
    if isinstance(texts, (bytes, bytearray, memoryview)) or not isinstance(texts, Iterable):
        raise InputError(f"texts must be a str or an iterable of str, got {type(texts).__name__}")
    return list(texts)


def _limit_pair(speed_range: object) -> tuple[float, float] | None:
    if speed_range is None:
        return None
    try:
        # unpacking is the check: anything but an iterable of two items raises TypeError / ValueError here
        lo, hi = cast("Iterable[object]", speed_range)
    except (TypeError, ValueError):
        raise InputError(f"speed_range must be (lo, hi) in m/s or None, got {speed_range!r}") from None
    if isinstance(lo, Real) and isinstance(hi, Real) and not isinstance(lo, bool) and not isinstance(hi, bool):
        return float(lo), float(hi)
    raise InputError(f"speed_range must be two numbers (lo, hi) in m/s, got {speed_range!r}")


def _limit_value(max_abs_curvature: object) -> float | None:
    if max_abs_curvature is None:
        return None
    if not isinstance(max_abs_curvature, Real) or isinstance(max_abs_curvature, bool):
        raise InputError(f"max_abs_curvature must be a number (1/m) or None, got {max_abs_curvature!r}")
    return float(max_abs_curvature)


def parse_actions(
    texts: str | Iterable[str] | npt.NDArray[np.str_ | np.object_],
    *,
    n: int = 6,
    mode: str = "lenient",
    speed_range: tuple[float, float] | None = DEFAULT_SPEED_RANGE,
    max_abs_curvature: float | None = DEFAULT_MAX_ABS_CURVATURE,
    history: npt.ArrayLike | None = None,
) -> ParsedActions:
    """Parse model answers into ``n`` (speed m/s, curvature 1/m) actions each.

    Modes (rules and worked examples in ``docs/parsing.md``):

    - ``"strict"``: the whole answer is ``[(v1, c1), …, (vn, cn)]`` and nothing else.
    - ``"lenient"`` (the default): the strict format is ``ok``; otherwise reasoning
      blocks (``<think>…</think>``) are dropped and the list of ``n`` actions the
      answer's structure gives is taken (``corrected``): bracketed pairs, ``[v c, …]``
      items, a flat list of ``2n`` numbers, speeds and curvatures in labelled lists or
      columns. Several *different* lists are ``ambiguous`` unless a correction or
      final-answer cue (``Wait``, ``Correction:``, ``Final answer:``, …) comes after an
      earlier one and before the last; a list equal to the frame's ``history`` is a
      quotation, skipped beside another list, only where its sentence calls it the past
      (``past``, ``previous``, ``history`` before it); cues win over that rule. A text
      without bracketed pairs gives exactly ``2n`` standalone numbers only where labels
      or the layout pair them. Malformed pairs, ranges (``4.5-5.0``), doubled signs and cut-off lists are ``failed`` with a
      reason — never re-paired or guessed.
    - ``"paper"``: the paper's own rules, to reproduce its FE / FE corr columns: ``ok``
      when the answer is a Python literal list of ``n`` tuples of 2 numbers; else
      ``corrected`` when at least ``2n`` numbers are found as maximal runs of digits,
      ``-`` and ``.`` of the form ``-?digits(.digits)?`` (the first ``2n`` are taken);
      else ``failed``. No plausibility gate.
    - ``"json"``: the answer is the JSON object ``{"actions": [[v, c], …]}`` (a
      provider's structured output; surrounding whitespace and a code fence allowed).

    Outside paper mode, answers with a speed outside ``speed_range`` (m/s, inclusive)
    or ``|curvature| > max_abs_curvature`` (1/m) are ``failed`` as ``"implausible"``;
    ``None`` disables either limit.

    Args:
        texts: one str, any iterable of str, or a 1-D NumPy array of str (dtype ``U``
            or ``object``).
        n: actions per answer (6 in the paper).
        history: None, or the (speed, curvature) history each prompt printed, shape
            (N, n, 2) (a frame's ``history_actions``), float64 (other dtypes are cast).
            A lenient candidate list equal to its row — compared as the float64 values
            the prompt's shortest round-trip decimals denote, so ``4.50`` is ``4.5`` —
            is a quotation, skipped when another candidate exists, only where a past word
            (``past``, ``previous``, ``history``, …) in its own sentence introduces it and no
            correction / final-answer cue does; otherwise it is a candidate like any other, so
            beside a different list without a cue it is ``ambiguous`` (alone it is the answer:
            a stopped car predicted to stay stopped). See docs/parsing.md. A row of NaN equals nothing (no history
            for that answer; :func:`history_rows` builds such arrays). Other modes ignore it.

    Returns:
        :class:`ParsedActions` with ``actions`` (N, n, 2), ``status``, ``reason`` and
        ``failure``. A bad answer never raises: it is ``failed`` with a reason.

    Raises:
        ValueError: ``texts`` is not text (the message names the first bad item), ``n``
            is not a positive int, ``mode`` is unknown, or a limit is malformed (not
            finite, ``lo >= hi``, curvature limit ``<= 0``), or ``history`` has another
            shape than (N, n, 2).

    >>> import lightemma
    >>> p = lightemma.parse_actions("Actions: [(5.0, 0.0), (5.2, 0.01), (5.4, 0.01), (5.5, 0.0), (5.5, 0.0), (5.6, 0.0)]")
    >>> p.status[0], p.actions[0, 1].tolist()
    ('corrected', [5.2, 0.01])
    """
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise InputError(f"n must be a positive integer, got {n!r}")
    if not isinstance(mode, str):
        raise InputError(f"mode must be one of {', '.join(PARSE_MODES)}, got {mode!r}")
    speed = _limit_pair(speed_range)
    curvature = _limit_value(max_abs_curvature)
    items = _as_list_of_str(texts)
    hist = None
    if history is not None:
        hist = np.ascontiguousarray(history, dtype=np.float64)
        if hist.shape != (len(items), n, 2):
            raise ShapeError(f"history must have shape ({len(items)}, {n}, 2) like the texts, got {hist.shape}")
    # the core checks every item is a str and the mode is one of PARSE_MODES (UnknownNameError naming them)
    actions, codes, failures, reasons = _core.parse_actions(
        cast("list[str]", items), n, cast("_ParseMode", mode), speed, curvature, hist
    )
    return ParsedActions(actions=actions, status=_STATUS_NAMES[codes], reason=reasons, failure=_FAILURE_NAMES[failures])


def history_rows(histories: Iterable[object], n: int = 6) -> npt.NDArray[np.float64]:
    """Histories for :func:`parse_actions`'s ``history``: a float64 (N, n, 2) array, one row per item.

    An item that is not ``n`` finite (speed, curvature) pairs (None, a record without its
    history, a wrong shape) becomes a row of NaN, which equals no list: that answer is
    parsed as without a history.
    """
    rows: list[npt.NDArray[np.float64]] = []
    for item in histories:
        try:
            row = np.asarray(item, dtype=np.float64)
        except (TypeError, ValueError):
            row = None
        if row is None or row.shape != (n, 2) or not np.isfinite(row).all():
            row = np.full((n, 2), np.nan)
        rows.append(row)
    return np.stack(rows) if rows else np.zeros((0, n, 2))


class Plausibility(TypedDict):
    """The plausibility limits as a run manifest records them (:func:`plausibility`)."""

    speed_range: list[float] | None  # [lo, hi], m/s
    max_abs_curvature: float | None  # 1/m


def plausibility(
    speed_range: object = DEFAULT_SPEED_RANGE, max_abs_curvature: object = DEFAULT_MAX_ABS_CURVATURE
) -> Plausibility:
    """The plausibility limits as a run manifest records them: ``{"speed_range": [lo, hi] | None,
    "max_abs_curvature": k | None}``.

    Raises ValueError for malformed limits, exactly as :func:`parse_actions` does.
    """
    speed = _limit_pair(speed_range)
    curvature = _limit_value(max_abs_curvature)
    parse_actions([], speed_range=speed, max_abs_curvature=curvature)  # validates (finite, lo < hi, > 0)
    return {"speed_range": None if speed is None else list(speed), "max_abs_curvature": curvature}
