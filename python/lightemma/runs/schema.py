"""The run record format as types: a frame record (one line of ``frames.jsonl``), its attempts and their calls.

docs/run.md and docs/definitions.md#run-records describe the format; the :class:`typing.TypedDict` classes here are
that description in code — which keys a record has (``Required``) or may have (``NotRequired``), and what each holds.
Every writer builds its records with :func:`frame_record`, :func:`attempt_record` and :func:`call_record` (the chain,
:mod:`lightemma.pipeline.chain`, for every backend, batch included; the reference importer,
:mod:`lightemma.runs.importer`), so a field is declared once, here, and a writer that leaves out a required field or
adds an undeclared one fails at once (:class:`RecordSchemaError`) instead of writing a record some reader
misreads. Readers annotate with the same classes.

The constructors keep the keys in the order the writer passes them: that order is the on-disk byte order of a
record, and each writer's order is as it was before these types existed (a run's ``frames.jsonl`` is
byte-identical; tests/unit/runs/test_run_schema.py pins it). JSON numbers are ``int`` or ``float``; a count, time or cost
that is unknown is ``None`` (docs/run.md, "Unknown stays unknown"); the bounds on them are
:mod:`lightemma.runs.records`' (:data:`~lightemma.runs.records.VALUE_BOUNDS`), checked by the readers.

:func:`schema_problem` checks a whole decoded record against these types (keys and the kinds of their values,
attempts, calls and samples included); the tests run it over every writer's records.
"""

# No ``from __future__ import annotations``: TypedDict reads Required / NotRequired off evaluated annotations only.
import types
import typing
from collections.abc import Mapping
from typing import Any, NotRequired, Required, TypedDict, Union, Unpack

Number = float  # a JSON number: an int or a float (typing's numeric tower: float accepts int), never a bool


class RecordSchemaError(TypeError):
    """A writer built a record the format does not allow (a required field left out, an undeclared one added).

    A programming error, not bad input: it is raised before anything is written."""


class CallRecord(TypedDict):
    """One model call of an attempt (``attempts[i].calls[j]``): its text or error, usage, time and cost.

    ``text`` is None when the call failed (``error`` holds the exception's class name, ``error_message`` its short,
    key-scrubbed message); tokens and cost None when not reported; ``seconds`` the call's wall time;
    ``finish_reason`` ``stop`` / ``length`` (None where unknown: imported runs). Imported runs store the prompt
    (``prompt``, or ``prompt_template`` + ``prompt_fill``: :mod:`lightemma.runs.stored_prompts`) and no
    ``cache_write_tokens``."""

    stage: str
    prompt: NotRequired[str | None]
    prompt_template: NotRequired[int]
    prompt_fill: NotRequired[Any]
    text: str | None
    error: str | None
    error_message: str | None
    input_tokens: int | None
    output_tokens: int | None
    seconds: Number | None
    cost_cents: Number | None
    cached: bool
    retries: int
    finish_reason: str | None
    reasoning_tokens: int | None
    cached_input_tokens: int | None
    cache_write_tokens: NotRequired[int | None]


class AttemptRecord(TypedDict):
    """One attempt of a frame's chain (``attempts[i]``): its calls, the stage-3 answer and how it parsed.

    ``status`` ``ok`` / ``corrected`` / ``failed``; ``failure`` the failure kind (``""`` when none, ``api_error``,
    ``truncated``, …: :data:`lightemma.definitions` ``PARSE_FAILURES``); ``error`` the last failed call's error
    class. The totals are over the attempt's calls (null when any call's is); imported runs have no
    reasoning or cache token totals."""

    attempt: int
    calls: list[CallRecord]
    answer: str | None
    status: str
    reason: str
    failure: str
    error: str | None
    input_tokens: int | None
    output_tokens: int | None
    reasoning_tokens: NotRequired[int | None]
    cached_input_tokens: NotRequired[int | None]
    cache_write_tokens: NotRequired[int | None]
    seconds: Number | None
    cost_cents: Number | None


class SampleRecord(TypedDict):
    """Sample ``sample`` (1..K-1) of a frame run with ``--samples K`` (``samples[i]`` of its record; sample 0 is the
    frame record itself): the fields of its own chain, as a frame record has them (docs/run.md#k-samples)."""

    sample: int
    status: str | None
    failure: str | None
    first_status: str | None
    n_attempts: int
    attempts: list[AttemptRecord]
    actions: list[list[Number]] | None
    trajectory: list[list[Number]] | None
    scene_text: str | None
    intent_text: str | None
    answer: str | None
    error: str | None
    seconds: Number | None
    call_seconds: Number | None
    input_tokens: int | None
    output_tokens: int | None
    reasoning_tokens: int | None
    cached_input_tokens: int | None
    cache_write_tokens: int | None
    cost_cents: Number | None
    cached: bool
    cached_calls: int
    retries: int


class FrameRecord(TypedDict, total=False):
    """One frame of a run: one line of ``frames.jsonl`` (docs/definitions.md#run-records).

    ``status`` the final parse status, ``first_status`` the first received answer's (FE counts it; None when no
    answer was received); ``actions`` (6, 2) ``[v m/s, κ 1/m]`` and ``trajectory`` (6, 2) metres, None when the frame
    failed; ``gt_positions`` (6, 2) metres and ``history_actions`` (6, 2) as the prompt had them; ``seconds`` the
    frame's wall time, ``call_seconds`` its calls' together; totals null when any call's is. Imported runs add the
    reference's own fields (``history_positions`` … ``source``) and have no reasoning or cache token totals; a
    ``--samples K`` run adds ``samples`` (K-1 entries)."""

    frame_id: Required[str]
    scene_name: Required[str]
    sample_token: Required[str]
    status: Required[str]
    failure: Required[str | None]
    first_status: Required[str | None]
    n_attempts: Required[int]
    attempts: Required[list[AttemptRecord]]
    actions: Required[list[list[Number]] | None]
    trajectory: Required[list[list[Number]] | None]
    gt_positions: Required[list[list[Number]] | None]
    history_actions: Required[list[list[Number]] | None]
    history_positions: NotRequired[Any]
    gt_actions: NotRequired[Any]
    scene_text: Required[str | None]
    intent_text: Required[str | None]
    answer: Required[str | None]
    error: Required[str | None]
    seconds: Required[Number | None]
    call_seconds: Required[Number | None]
    input_tokens: Required[int | None]
    output_tokens: Required[int | None]
    reasoning_tokens: NotRequired[int | None]
    cached_input_tokens: NotRequired[int | None]
    cache_write_tokens: NotRequired[int | None]
    cost_cents: Required[Number | None]
    cached: Required[bool]
    cached_calls: Required[int]
    retries: Required[int]
    samples: NotRequired[list[SampleRecord]]
    keyframe_index: NotRequired[int | None]
    timestamp: NotRequired[Any]
    image_name: NotRequired[str | None]
    image_path: NotRequired[str | None]
    camera_params: NotRequired[Any]
    ego_position: NotRequired[Any]
    ego_heading: NotRequired[Any]
    source: NotRequired[dict[str, Any]]


_RECORD_TYPES = (CallRecord, AttemptRecord, SampleRecord, FrameRecord)
_HINTS: dict[type, dict[str, Any]] = {t: typing.get_type_hints(t) for t in _RECORD_TYPES}
_KEYS: dict[type, tuple[frozenset[str], frozenset[str]]] = {
    t: (frozenset(t.__required_keys__), frozenset(t.__required_keys__ | t.__optional_keys__)) for t in _RECORD_TYPES
}


def _keys_problem(kind: type, record: Mapping[str, Any]) -> str | None:
    """Which required keys of ``kind`` ``record`` lacks, or which keys it has that ``kind`` does not declare."""
    required, allowed = _KEYS[kind]
    missing = required.difference(record)
    if missing:
        return f"lacks {', '.join(sorted(missing))}"
    extra = set(record).difference(allowed)
    if extra:
        return f"has undeclared {', '.join(sorted(extra))}"
    return None


def _checked(kind: type, fields: dict[str, Any]) -> Any:
    problem = _keys_problem(kind, fields)
    if problem is not None:
        raise RecordSchemaError(f"a {kind.__name__} {problem} (lightemma.runs.schema)")
    return fields


def call_record(**fields: Unpack[CallRecord]) -> CallRecord:
    """A call record of ``fields`` (in the order given). Raises :class:`RecordSchemaError` when a required field is
    missing or an undeclared one given."""
    return typing.cast(CallRecord, _checked(CallRecord, dict(fields)))


def attempt_record(**fields: Unpack[AttemptRecord]) -> AttemptRecord:
    """An attempt record of ``fields`` (in the order given); :class:`RecordSchemaError` as :func:`call_record`."""
    return typing.cast(AttemptRecord, _checked(AttemptRecord, dict(fields)))


def frame_record(**fields: Unpack[FrameRecord]) -> FrameRecord:
    """A frame record (a line of ``frames.jsonl``) of ``fields`` (in the order given, the order written);
    :class:`RecordSchemaError` as :func:`call_record`."""
    return typing.cast(FrameRecord, _checked(FrameRecord, dict(fields)))


def _value_problem(hint: Any, value: Any, where: str) -> str | None:
    """Why ``value`` is not of the annotated type ``hint`` (None, str, int, float (an int too), bool, lists of
    them, a record class, Any), else None."""
    if hint is Any:
        return None
    origin = typing.get_origin(hint)
    if origin in (Union, types.UnionType):
        options = typing.get_args(hint)
        if any(_value_problem(option, value, where) is None for option in options):
            return None
        others = [option for option in options if option is not type(None)]
        if len(others) == 1:  # X | None holding something that is no X: what is wrong with it as an X
            return _value_problem(others[0], value, where)
        return f"{where} is {type(value).__name__} {_short(value)}, expected {_name(hint)}"
    if hint is type(None):
        return None if value is None else f"{where} is {type(value).__name__}, expected null"
    if hint in _HINTS:
        return schema_problem(value, hint, where)
    if origin is list:
        if type(value) is not list:
            return f"{where} is {type(value).__name__}, expected a list"
        (item,) = typing.get_args(hint)
        for i, entry in enumerate(value):
            problem = _value_problem(item, entry, f"{where}[{i}]")
            if problem is not None:
                return problem
        return None
    if origin is dict:
        return None if type(value) is dict else f"{where} is {type(value).__name__}, expected an object"
    if hint is bool:
        ok = type(value) is bool
    elif hint is int:
        ok = type(value) is int
    elif hint is float:
        ok = type(value) in (int, float)
    else:
        ok = isinstance(value, hint)
    return None if ok else f"{where} is {type(value).__name__} {_short(value)}, expected {_name(hint)}"


def _name(hint: Any) -> str:
    return getattr(hint, "__name__", None) or str(hint).replace("typing.", "")


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:39] + "…"


def schema_problem(record: Any, kind: type = FrameRecord, where: str = "") -> str | None:
    """Why the decoded ``record`` is not a ``kind`` (:class:`FrameRecord` by default; attempts, calls and samples
    checked within), naming the first field that is wrong (``attempts[0].calls[2].seconds is str …``), else None."""
    label = where or kind.__name__
    if not isinstance(record, dict):
        return f"{label} is {type(record).__name__}, expected an object"
    problem = _keys_problem(kind, record)
    if problem is not None:
        return f"{label} {problem}"
    hints = _HINTS[kind]
    for key, value in record.items():
        inner = typing.get_args(hints[key]) if typing.get_origin(hints[key]) in (Required, NotRequired) else None
        hint = inner[0] if inner else hints[key]
        problem = _value_problem(hint, value, f"{where}.{key}" if where else key)
        if problem is not None:
            return problem
    return None
