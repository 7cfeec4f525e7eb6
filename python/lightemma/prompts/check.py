"""Check a prompt set against the prompts an imported run stored (``lightemma prompts check``).

A run imported from the reference scripts keeps each stage's prompt as the
reference sent it (``attempts[0].calls[i]``, whole or as a template of the run
and the frame's fill: :func:`lightemma.runs.stored_prompts.call_prompt`). Rendering a prompt set with
that frame's own stage texts and history, and folding whitespace the way the
reference stored its prompts (lines of at most 80 characters, joined with one
space), must give the same text if the set says what the reference said.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lightemma._text import unicode_clean
from lightemma.definitions import STAGES
from lightemma.errors import UserError
from lightemma.frames import history_placeholders
from lightemma.prompts import PromptSet
from lightemma.runs.reference import as_stored
from lightemma.runs.store import iter_records, read_manifest
from lightemma.runs.stored_prompts import call_prompt, frame_texts

CONTEXT = 30  # characters shown before the first difference


@dataclass
class Difference:
    """Where a rendered prompt first departs from the stored one (``position`` is 0-based)."""

    frame_id: str
    position: int
    stored: str
    rendered: str

    def excerpts(self) -> tuple[str, str]:
        """The two texts around the difference, from :data:`CONTEXT` characters before it."""
        start = max(0, self.position - CONTEXT)
        lead = "…" if start else ""

        def cut(text: str) -> str:
            piece = text[start : self.position + 40]
            return (
                lead + piece + ("…" if len(text) > self.position + 40 else "") if piece else lead + "(text ends here)"
            )

        return cut(self.stored), cut(self.rendered)


@dataclass
class StageCheck:
    """One stage over the run's frames: how many were compared, how many matched, the first difference."""

    stage: str
    compared: int = 0
    identical: int = 0
    no_prompt: int = 0  # frames without a stored prompt for this stage
    first: Difference | None = None

    @property
    def ok(self) -> bool:
        return self.compared > 0 and self.identical == self.compared


def first_difference(a: str, b: str) -> int | None:
    """Index of the first character where ``a`` and ``b`` differ (the shorter one's length if one is a prefix), or None."""
    for i, (x, y) in enumerate(zip(a, b)):
        if x != y:
            return i
    return None if len(a) == len(b) else min(len(a), len(b))


def _texts(calls: list[Any]) -> dict[str | None, Mapping[str, Any]]:
    return {c.get("stage"): c for c in calls if isinstance(c, Mapping)}


def _rendered(
    prompts: PromptSet, stage: str, calls: Mapping[str | None, Mapping[str, Any]], history: dict[str, str]
) -> str:
    def text(name: str) -> str:
        call: Mapping[str, Any] = calls.get(name) or {}
        text = call.get("text")
        return text if text is not None else (call.get("error_message") or "")

    if stage == "scene":
        return prompts.render("scene")
    if stage == "intent":
        return prompts.render("intent", scene=text("scene"), **history)
    return prompts.render("actions", scene=text("scene"), intent=text("intent"), **history)


def check_prompts(prompts: PromptSet, run_dir: str | os.PathLike[str], *, limit: int | None = None) -> list[StageCheck]:
    """Compare ``prompts`` rendered for each frame of ``run_dir`` with the prompts the run stored, per stage.

    Raises :class:`UserError` when the run is not an imported one (no stored prompts).
    """
    run_dir = Path(run_dir)
    manifest = read_manifest(run_dir)
    if not manifest.get("imported"):
        raise UserError(
            f"{run_dir} was not imported from reference results, so it stores no prompts to check against "
            "(lightemma import makes such runs)"
        )
    templates = (
        (manifest.get("prompt_set") or {}).get("templates") if isinstance(manifest.get("prompt_set"), Mapping) else None
    )
    checks = {stage: StageCheck(stage) for stage in STAGES}
    seen = 0
    for record in iter_records(run_dir):
        attempts = record.get("attempts") or []
        if not attempts or not isinstance(attempts[0], Mapping) or record.get("history_actions") is None:
            continue
        calls = _texts(attempts[0].get("calls") or [])
        texts = frame_texts(list(calls.values()))
        history = history_placeholders(record["history_actions"])
        for stage, check in checks.items():
            stored = call_prompt(calls.get(stage) or {}, texts, templates)
            if not isinstance(stored, str):
                check.no_prompt += 1
                continue
            rendered = as_stored(_rendered(prompts, stage, calls, history))
            check.compared += 1
            at = first_difference(stored, rendered)
            if at is None:
                check.identical += 1
            elif check.first is None:
                check.first = Difference(record["frame_id"], at, stored, rendered)
        seen += 1
        if limit is not None and seen >= limit:
            break
    return list(checks.values())


def format_checks(checks: list[StageCheck], prompts: PromptSet, run_dir: str | os.PathLike[str]) -> str:
    """The report ``lightemma prompts check`` prints."""
    frames = max((c.compared + c.no_prompt for c in checks), default=0)
    lines = [f"prompt set {prompts.name!r} ({prompts.hash}) against {frames} frame(s) of {run_dir}"]
    for check in checks:
        head = f"{check.stage:<8} {check.identical}/{check.compared} frame(s) identical"
        if check.no_prompt:
            head += f" ({check.no_prompt} without a stored prompt)"
        if check.first is None:
            lines.append(head)
            continue
        stored, rendered = (unicode_clean(text) for text in check.first.excerpts())  # printable, lone surrogates too
        lines += [
            f"{head}; first difference in {check.first.frame_id} at character {check.first.position + 1}:",
            f"           run:      {stored}",
            f"           rendered: {rendered}",
        ]
    return "\n".join(lines)
