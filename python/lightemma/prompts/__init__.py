"""Prompt sets: the three stages of the chain as versioned data.

A prompt set is a JSON file in this package (``<name>.json``) with a ``name``,
a ``description`` and one template per stage (``scene``, ``intent``,
``actions``). Templates use the placeholders ``{scene}``, ``{intent}`` and the
history as ``{history}`` (pairs of plain decimals) and/or ``{speeds}`` and
``{curvatures}`` (the two lists as the reference scripts printed them, see
:func:`lightemma.frames.format_python_list`); nothing else in them is special,
so braces, brackets and parentheses in the wording are taken literally. The
intent and actions templates must carry the history: ``{history}``, or both
``{speeds}`` and ``{curvatures}``.

Every run records the prompt set's name and its content hash (SHA-256 of the
canonical JSON of the file's content), so a result can always be traced to the
exact wording, and a resumed run refuses to continue under different wording.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from importlib import resources
from typing import Any

from lightemma.backends.base import STAGES
from lightemma.errors import UserError

DEFAULT_PROMPT_SET = "lightemma-v1"
# placeholders each stage fills in; HISTORY_FORMS: one of these sets must appear where "history" is listed
PLACEHOLDERS = {"scene": (), "intent": ("scene", "history"), "actions": ("scene", "history", "intent")}
HISTORY_FORMS: tuple[tuple[str, ...], ...] = (("history",), ("speeds", "curvatures"))
HISTORY_KEYS = ("history", "speeds", "curvatures")


def content_hash(data: dict[str, Any]) -> str:
    """``sha256:<hex>`` of the canonical JSON (sorted keys, no spaces) of a prompt set's content."""
    canonical = json.dumps(data, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    return "sha256:" + hashlib.sha256(canonical.encode("utf-8")).hexdigest()


@dataclass(frozen=True)
class PromptSet:
    """A named, hashed set of stage templates."""

    name: str
    description: str
    stages: dict[str, str]
    hash: str

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, origin: str = "prompt set") -> PromptSet:
        """Validate ``data`` (the JSON content) and build the set; errors name ``origin``."""
        stages = data.get("stages")
        if not isinstance(data.get("name"), str) or not isinstance(stages, dict):
            raise UserError(f"{origin}: a prompt set needs a string 'name' and a 'stages' object")
        missing = [s for s in STAGES if not isinstance(stages.get(s), str)]
        if missing:
            raise UserError(f"{origin}: stage template(s) {', '.join(missing)} missing (need {', '.join(STAGES)})")
        for stage, needed in PLACEHOLDERS.items():
            template = stages[stage]
            absent = [p for p in needed if p != "history" and "{" + p + "}" not in template]
            if "history" in needed and not any(all("{" + p + "}" in template for p in form) for form in HISTORY_FORMS):
                absent.append("history")
            if absent:
                names = ", ".join("{history} (or {speeds} and {curvatures})" if p == "history" else "{" + p + "}" for p in absent)
                raise UserError(f"{origin}: the {stage!r} template lacks placeholder(s) {names}")
        return cls(name=data["name"], description=str(data.get("description", "")), stages=dict(stages), hash=content_hash(data))

    def render(self, stage: str, *, scene: str = "", history: str = "", intent: str = "", speeds: str = "", curvatures: str = "") -> str:
        """The text of ``stage`` with the earlier stages' texts and the history filled in.

        ``history``, ``speeds`` and ``curvatures`` are the renderings of
        :func:`lightemma.frames.history_placeholders`.
        """
        values = {"scene": scene, "history": history, "intent": intent, "speeds": speeds, "curvatures": curvatures}
        text = self.stages[stage]
        keys = [k for k in PLACEHOLDERS[stage] if k != "history"] + (list(HISTORY_KEYS) if "history" in PLACEHOLDERS[stage] else [])
        for key in keys:
            text = text.replace("{" + key + "}", values[key].strip())
        return text

    def describe(self) -> dict[str, str]:
        """What a run manifest records about the prompt set."""
        return {"name": self.name, "hash": self.hash}


def available_prompt_sets() -> list[str]:
    """Names of the prompt sets shipped with lightemma."""
    return sorted(p.name[: -len(".json")] for p in resources.files(__package__).iterdir() if p.name.endswith(".json"))


def load_prompt_set(name: str = DEFAULT_PROMPT_SET) -> PromptSet:
    """Load a shipped prompt set by name, or a prompt-set JSON file by path (read afresh each time: it may be edited)."""
    if name.endswith(".json"):
        origin = name
        try:
            with open(name, encoding="utf-8") as fh:
                data = json.load(fh)
        except (OSError, json.JSONDecodeError) as exc:
            raise UserError(f"prompt set file {name}: {exc}") from None
    else:
        resource = resources.files(__package__) / f"{name}.json"
        if not resource.is_file():
            raise UserError(f"unknown prompt set {name!r}; available: {', '.join(available_prompt_sets())}")
        origin = f"prompt set {name!r}"
        data = json.loads(resource.read_text(encoding="utf-8"))
    if not isinstance(data, dict):
        raise UserError(f"{origin}: expected a JSON object")
    return PromptSet.from_dict(data, origin=origin)
