"""Re-scoring a run's stored answers under another parse definition (``evaluate --parse``).

Every attempt of a run keeps its raw stage-3 answer, so a run can be scored
again under ``lenient``, ``strict`` or ``paper`` parsing (with other
plausibility limits) without asking the model again. Per frame:

* every attempt's answer is parsed again, in order, with the frame's recorded
  ``history_actions`` (a list in the answer equal to it and called the past is a
  quotation, docs/parsing.md; a record without a history is parsed without one); attempts without an
  answer — API errors — stay as they were;
* the frame's actions are those of the first attempt whose answer passes: what a
  run under that definition would have stopped at. Its status is the frame's; when
  no answer passes the frame is ``failed`` (the run did not ask again, so this is
  all there is);
* the first status is that of the first received answer (FE and FE corr);
* trajectories are integrated again from the new actions with the run's own
  integrator (by the loader, in one batch).

A run's own definition is in its manifest (``params.parse``): ``paper`` for
imported runs, the run's parse settings otherwise; runs that predate the
setting were parsed ``lenient``.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from lightemma.actions import DEFAULT_MAX_ABS_CURVATURE, DEFAULT_SPEED_RANGE, history_rows, parse_actions
from lightemma.definitions import PARSE_MODES
from lightemma.errors import UserError

_BLOCK = 2048  # records re-parsed per parser call


@dataclass(frozen=True)
class ParseDefinition:
    """How answers are read: a parse mode plus, for ``lenient``/``strict``, the plausibility limits.

    Limits left out take the parser's defaults (:data:`lightemma.actions.DEFAULT_SPEED_RANGE`,
    :data:`~lightemma.actions.DEFAULT_MAX_ABS_CURVATURE`) and are recorded as such; the
    paper's rules have none.
    """

    mode: str = "lenient"
    speed_range: tuple[float, float] | None = None
    max_abs_curvature: float | None = None

    def __post_init__(self) -> None:
        if self.mode not in PARSE_MODES:
            raise UserError(f"unknown parse mode {self.mode!r} (choose from {', '.join(PARSE_MODES)})")
        if self.mode == "paper":
            if self.speed_range is not None or self.max_abs_curvature is not None:
                raise UserError(
                    "--speed-range and --max-curvature apply to lenient, strict and json parsing; the paper's rules have no plausibility limits"
                )
        else:
            speed = DEFAULT_SPEED_RANGE if self.speed_range is None else self.speed_range
            curvature = DEFAULT_MAX_ABS_CURVATURE if self.max_abs_curvature is None else self.max_abs_curvature
            object.__setattr__(self, "speed_range", (float(speed[0]), float(speed[1])))
            object.__setattr__(self, "max_abs_curvature", float(curvature))
        if self.speed_range is not None:
            lo, hi = self.speed_range
            if not lo < hi:
                raise UserError(f"--speed-range needs LO < HI, got {lo} {hi}")
        if self.max_abs_curvature is not None and not self.max_abs_curvature > 0:
            raise UserError(f"--max-curvature must be positive, got {self.max_abs_curvature}")

    def parser_options(self) -> dict[str, Any]:
        """Keyword arguments for :func:`lightemma.parse_actions`."""
        options: dict[str, Any] = {"mode": self.mode}
        if self.speed_range is not None:
            options["speed_range"] = tuple(self.speed_range)
        if self.max_abs_curvature is not None:
            options["max_abs_curvature"] = self.max_abs_curvature
        return options

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"mode": self.mode}
        if self.speed_range is not None:
            out["speed_range"] = list(self.speed_range)
        if self.max_abs_curvature is not None:
            out["max_abs_curvature"] = self.max_abs_curvature
        return out

    def label(self) -> str:
        """Short text for tables: ``paper``, ``lenient``; limits only where not the defaults (``strict v∈[0, 30] |κ|≤0.5``)."""
        if self.mode == "paper":
            return "paper"

        extra = []
        if self.speed_range != DEFAULT_SPEED_RANGE:
            assert self.speed_range is not None  # __post_init__ sets it outside paper mode
            extra.append(f"v∈[{self.speed_range[0]:g}, {self.speed_range[1]:g}]")
        if self.max_abs_curvature != DEFAULT_MAX_ABS_CURVATURE:
            extra.append(f"|κ|≤{self.max_abs_curvature:g}")
        return " ".join([self.mode, *extra])

    @classmethod
    def from_dict(cls, data: Any) -> ParseDefinition:
        if isinstance(data, str):
            return cls(mode=data)
        if not isinstance(data, Mapping):
            return cls()
        speed = data.get("speed_range")
        return cls(
            mode=str(data.get("mode") or "lenient"),
            speed_range=(float(speed[0]), float(speed[1]))
            if isinstance(speed, (list, tuple)) and len(speed) == 2
            else None,
            max_abs_curvature=float(data["max_abs_curvature"]) if data.get("max_abs_curvature") is not None else None,
        )


def recorded_parse(manifest: Mapping[str, Any]) -> ParseDefinition:
    """The definition a run's records were parsed with (``params.parse`` in its manifest; ``lenient`` if absent)."""
    params_value = manifest.get("params")
    params: Mapping[str, Any] = params_value if isinstance(params_value, Mapping) else {}
    return ParseDefinition.from_dict(params.get("parse"))


def _attempts(record: Mapping[str, Any]) -> list[dict[str, Any]]:
    attempts = record.get("attempts")
    if isinstance(attempts, list) and attempts:
        return [dict(a) for a in attempts if isinstance(a, Mapping)]
    answer = record.get("answer")
    return [{"answer": answer, "status": record.get("status"), "reason": ""}] if isinstance(answer, str) else []


def _apply(
    record: dict[str, Any], attempts: list[dict[str, Any]], parsed: list[tuple[str, str, str, Any] | None]
) -> dict[str, Any]:
    """The record with statuses, actions and first status from the new parses (trajectory left to the loader)."""
    first = None
    chosen = None
    for attempt, result in zip(attempts, parsed):
        if result is None:
            continue
        status, reason, failure, actions = result
        attempt.update(status=status, reason=reason, failure=failure)
        first = first or status
        if chosen is None and status != "failed":
            chosen = (status, failure, actions)
    out = dict(record)
    out["attempts"] = attempts
    if first is not None:
        out["first_status"] = first
    if chosen is not None:
        out["status"], out["failure"], out["actions"] = chosen[0], chosen[1], chosen[2]
    else:
        out["status"], out["actions"] = "failed", None
        out["failure"] = next((a.get("failure") for a in reversed(attempts) if a.get("failure")), record.get("failure"))
    out["trajectory"] = None
    return out


def rescored(
    records: Iterable[dict[str, Any]], definition: ParseDefinition, *, block: int = _BLOCK
) -> Iterator[dict[str, Any]]:
    """Stream ``records`` re-parsed under ``definition`` (see the module docstring); one parser call per block."""
    options = definition.parser_options()
    pending: list[tuple[dict[str, Any], list[dict[str, Any]]]] = []

    def flush() -> Iterator[dict[str, Any]]:
        answers = [a["answer"] for _, attempts in pending for a in attempts if isinstance(a.get("answer"), str)]
        # each answer with its frame's history, as the prompt printed it: a list quoting it as the past is skipped
        histories = history_rows(
            record.get("history_actions")
            for record, attempts in pending
            for a in attempts
            if isinstance(a.get("answer"), str)
        )
        parsed = parse_actions(answers, n=6, history=histories, **options) if answers else None
        k = 0
        for record, attempts in pending:
            results: list[tuple[str, str, str, Any] | None] = []
            for attempt in attempts:
                if isinstance(attempt.get("answer"), str):
                    assert parsed is not None
                    ok = parsed.status[k] != "failed"
                    results.append(
                        (
                            str(parsed.status[k]),
                            str(parsed.reason[k]),
                            str(parsed.failure[k]),
                            parsed.actions[k].tolist() if ok else None,
                        )
                    )
                    k += 1
                else:
                    results.append(None)
            yield _apply(record, attempts, results)
        pending.clear()

    for record in records:
        pending.append((record, _attempts(record)))
        if len(pending) >= block:
            yield from flush()
    if pending:
        yield from flush()
