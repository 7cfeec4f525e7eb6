"""Facts read off one frame record (a line of ``frames.jsonl``), for any reader of runs.

Records written since the parser's failure kinds carry ``first_status`` = the status of the
first stage-3 answer *received* (None when every attempt ended in an API error). Older
records set it from the first attempt even when that attempt was an API error; the helpers
below read both the same way.
"""

from __future__ import annotations

import gc
import json
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from typing import Any

MAX_NUMBER_DIGITS = 18  # an integer token longer than this (beyond 10^18) is no count, index or coordinate


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
