"""Facts read off one frame record (a line of ``frames.jsonl``), for any reader of runs.

Records written since the parser's failure kinds carry ``first_status`` = the status of the
first stage-3 answer *received* (None when every attempt ended in an API error). Older
records set it from the first attempt even when that attempt was an API error; the helpers
below read both the same way.
"""

from __future__ import annotations

import gc
import json
import numbers
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from typing import Any

from lightemma.definitions import STATUSES

MAX_NUMBER_DIGITS = 18  # an integer token longer than this (beyond 10^18) is no count, index or coordinate

# Bounds on a record's numbers (docs/run.md, "Limits"). A value beyond them is no measurement: the writers record it as
# unknown (None, :func:`bounded_values`), the readers skip a line holding one (:func:`record_problem`).
MAX_TOKENS = 10**9  # tokens of one call, and of a frame's calls together (a whole number 0..10^9)
MAX_SECONDS = 2_592_000.0  # seconds of one call, and of one frame: 30 days (a batched frame waits for 3 waves of
# batches of up to 24 h each, and their resubmissions)
MAX_COST_CENTS = 1e9  # cents of one call, and of a frame's calls together (10 million dollars)
MAX_POSITION_M = 1e5  # |coordinate| of a ground-truth position, metres (100 km from the ego vehicle)

TOKEN_FIELDS = ("input_tokens", "output_tokens", "reasoning_tokens", "cached_input_tokens", "cache_write_tokens")
SECONDS_FIELDS = ("seconds", "call_seconds")
COST_FIELDS = ("cost_cents",)
VALUE_BOUNDS: dict[str, float] = {
    **dict.fromkeys(TOKEN_FIELDS, MAX_TOKENS),
    **dict.fromkeys(SECONDS_FIELDS, MAX_SECONDS),
    **dict.fromkeys(COST_FIELDS, MAX_COST_CENTS),
}
_NUMBER_TYPES = (int, float)
_BOUND_ITEMS = tuple(VALUE_BOUNDS.items())


def token_count(value: Any) -> int | None:
    """``value`` as a token count (a whole number 0..:data:`MAX_TOKENS`; ``12.0`` reads as 12), else None."""
    if type(value) is int:
        return value if 0 <= value <= MAX_TOKENS else None
    if type(value) is float and value.is_integer() and 0 <= value <= MAX_TOKENS:
        return int(value)
    return None


def in_bounds(value: Any, bound: float) -> bool:
    """Whether ``value`` is a number (not a bool; a NumPy scalar is one) in 0..``bound`` (so finite)."""
    if type(value) in _NUMBER_TYPES:
        return 0 <= value <= bound
    if not isinstance(value, numbers.Real) or isinstance(value, bool):
        return False
    return bool(0 <= value <= bound)  # type: ignore[operator]  # typeshed's Real compares with a Real only


def value_problem(name: str, value: Any) -> str | None:
    """Why ``value`` cannot be the record field ``name`` (a count, time or cost: None or a number within its bound), else None."""
    if value is None:
        return None
    bound = VALUE_BOUNDS[name]
    if in_bounds(value, bound):
        return None
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        return f"{name} = {_shown(value)} is outside 0..{bound:g}"
    return f"{name} is {type(value).__name__} {_shown(value)}, expected a number or null"


def _shown(value: Any) -> str:
    try:
        text = repr(value)
    except (ValueError, RecursionError):  # an int of over 4,300 digits, or nested beyond the stack
        return f"a {type(value).__name__} too large to show"
    return text if len(text) <= 40 else text[:39] + "…"


def _bounded_fields(values: Mapping[str, Any], where: str, problems: list[str] | None) -> dict[str, Any] | None:
    """A copy of ``values`` with each count/time/cost out of kind or range as None, or None when every one is fine."""
    out = None
    for name, bound in _BOUND_ITEMS:
        value = values.get(name)
        if value is None or (type(value) in _NUMBER_TYPES and 0 <= value <= bound):  # the common case, inline
            continue
        if not in_bounds(value, bound):
            if out is None:
                out = dict(values)
            out[name] = None
            if problems is not None:
                problems.append(f"{where}{value_problem(name, value)}")
    return out


def _bounded_items(
    items: Any, where: str, bound: Callable[[Mapping[str, Any], str], dict[str, Any] | None]
) -> list | None:
    """A copy of the list ``items`` with each mapping in it as ``bound(item, "where[i].")`` made it, or None when
    ``items`` is no list or nothing in it changed."""
    if type(items) is not list:
        return None
    out = None
    for i, item in enumerate(items):
        fixed = bound(item, f"{where}[{i}].") if isinstance(item, Mapping) else None
        if fixed is not None:
            out = out if out is not None else list(items)
            out[i] = fixed
    return out


def _bounded_attempt(attempt: Mapping[str, Any], where: str, problems: list[str] | None) -> dict[str, Any] | None:
    """An attempt with its own and its calls' counts, times and costs bounded (None when nothing changed)."""
    out = _bounded_fields(attempt, where, problems)
    calls = _bounded_items(attempt.get("calls"), f"{where}calls", lambda call, at: _bounded_fields(call, at, problems))
    if calls is not None:
        out = {**(out if out is not None else attempt), "calls": calls}
    return out


def bounded_values(record: Mapping[str, Any], problems: list[str] | None = None) -> Mapping[str, Any]:
    """``record`` with every token count, time and cost that is not a number within its bound (:data:`VALUE_BOUNDS`) as
    None (unknown) — at the top, in each attempt and in each attempt's calls; each replacement is described in ``problems``.

    The record itself when nothing needed replacing (the common case: no copy), else a copy (the input is never changed).
    """
    out = _bounded_fields(record, "", problems)
    attempts = _bounded_items(
        record.get("attempts"), "attempts", lambda attempt, where: _bounded_attempt(attempt, where, problems)
    )
    if attempts is not None:
        out = {**(out if out is not None else record), "attempts": attempts}
    return record if out is None else out


def record_problem(record: Mapping[str, Any]) -> str | None:
    """Why a decoded line of ``frames.jsonl`` is no usable record (the line is then skipped, named in a warning), else None.

    Checked: ``frame_id`` a string; ``status`` and ``first_status`` null or one of :data:`STATUSES`; ``failure``
    null or a string; each attempt's ``status`` null or a string; the frame's token counts, times and cost null or
    numbers within :data:`VALUE_BOUNDS`. (Ground-truth positions beyond :data:`MAX_POSITION_M` make the record one
    without usable ground truth, judged with the columns: :mod:`lightemma.evaluation.loading`.)
    """
    if not isinstance(record, dict):
        return f"is {type(record).__name__}, expected an object"
    if not isinstance(record.get("frame_id"), str):
        return "has no frame_id string"
    for key in ("status", "first_status"):
        value = record.get(key)
        if value is not None and (type(value) is not str or value not in STATUSES):
            return f"{key} is {_shown(value)}, expected one of {', '.join(STATUSES)} or null"
    failure = record.get("failure")
    if failure is not None and type(failure) is not str:
        return f"failure is {type(failure).__name__} {_shown(failure)}, expected a string or null"
    for name in VALUE_BOUNDS:
        value = record.get(name)
        if value is not None and not in_bounds(value, VALUE_BOUNDS[name]):
            return value_problem(name, value)
    attempts = record.get("attempts")
    if type(attempts) is list:
        for i, attempt in enumerate(attempts):
            if isinstance(attempt, Mapping):
                status = attempt.get("status")
                if status is not None and type(status) is not str:
                    return (
                        f"attempts[{i}].status is {type(status).__name__} {_shown(status)}, expected a string or null"
                    )
    return None


def loads_bounded(data: bytes | str) -> Any:
    """``json.loads`` that refuses what would crash or mislead later: nesting too deep for the decoder
    (``RecursionError``) and integers of more than :data:`MAX_NUMBER_DIGITS` digits (10^400 tokens
    overflow every float). Raises :class:`ValueError` naming the problem (``json.JSONDecodeError``
    for plain syntax errors).

    The integer check is a ``parse_int`` hook: json's C scanner calls it for integer tokens only
    (floats, strings and structure stay in C), which costs far less than scanning the text.
    """
    try:
        return json.loads(data, parse_int=_bounded_int)
    except RecursionError:
        raise ValueError("nested too deeply to decode") from None


@contextmanager
def gc_paused() -> Iterator[None]:
    """The cyclic garbage collector paused, its state restored after: for reading many JSON trees (records, scene
    files), which hold no cycles and are freed by reference counting; the collector would only scan them again and
    again as they pile up (~12 % of an import's time)."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def _bounded_int(token: str) -> int:
    if len(token) > MAX_NUMBER_DIGITS and len(token.lstrip("-")) > MAX_NUMBER_DIGITS:
        raise ValueError(f"holds an integer of {len(token.lstrip('-'))} digits (at most {MAX_NUMBER_DIGITS} are read)")
    return int(token)


def _attempts(record: Mapping[str, Any]) -> list[Mapping[str, Any]] | None:
    """The record's attempts when each says whether it got an answer, else None (e.g. imported records)."""
    attempts = record.get("attempts")
    if isinstance(attempts, list) and attempts and all(isinstance(a, Mapping) and "answer" in a for a in attempts):
        return attempts
    return None


def attempt_received(attempt: Mapping[str, Any]) -> bool:
    """Whether an attempt got a stage-3 answer: not when it ended in an API error, nor when an
    earlier stage's text was cut off (``failure: "truncated"`` without an answer; a cut-off stage-3
    answer *was* received). In records older than ``failure``: whether it has answer text."""
    if "failure" in attempt:
        failure = attempt["failure"]
        return failure != "api_error" and not (failure == "truncated" and attempt["answer"] is None)
    return attempt["answer"] is not None


def answer_received(record: Mapping[str, Any]) -> bool:
    """Whether any stage-3 answer of the frame was received (not all its calls failed at the provider)."""
    attempts = _attempts(record)
    if attempts is not None:
        return any(attempt_received(a) for a in attempts)
    return record.get("first_status", record.get("status")) is not None


def first_answer_status(record: Mapping[str, Any]) -> Any:
    """The parse status of the frame's first received answer (None when none was received).

    Without attempts to look at, ``first_status`` (else ``status``) as recorded.
    """
    attempts = _attempts(record)
    if attempts is not None:
        return next((a.get("status") for a in attempts if attempt_received(a)), None)
    first = record.get("first_status")
    return first if first is not None else record.get("status")
