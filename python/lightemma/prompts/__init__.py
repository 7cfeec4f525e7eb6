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

A set may also carry ``variants``: templates for the request variants of a run
that replace some of the paper's stages —

* ``structured`` (``--answer-format structured``): the actions template asks for
  the JSON object ``{"actions": [[v, c], …]}`` instead of the bracketed list;
* ``conversation`` (``--chain conversation``): stages 2 and 3 continue one
  conversation, so their templates do not paste the earlier stages' texts
  (those are the assistant turns before them); the intent template carries the
  history, the actions template needs no placeholder;
* ``conversation+structured``: both at once;
* ``no-history`` (``--inputs no-history``, :mod:`lightemma.inputs`): the templates without the history
  numbers and the sentence that introduces them — a ``no-history`` template may hold no ``{history}``,
  ``{speeds}`` or ``{curvatures}``, and with the variant in place no stage may; combined with the others
  as ``no-history+structured``, ``conversation+no-history`` and ``conversation+no-history+structured``
  (parts in that order).

The set's ``hash`` covers its name, description and stages (the paper's chain; a set
without variants hashes as before variants existed); a run in a variant records the
variant's name and ``variant_hash``, the hash of that variant's templates, too.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass, field, replace
from importlib import resources
from typing import Any

from lightemma._text import without_lone_surrogates
from lightemma.definitions import STAGES
from lightemma.errors import InputError, UserError

DEFAULT_PROMPT_SET = "lightemma-v1"
# placeholders each stage fills in; HISTORY_FORMS: one of these sets must appear where "history" is listed
PLACEHOLDERS = {"scene": (), "intent": ("scene", "history"), "actions": ("scene", "history", "intent")}
HISTORY_FORMS: tuple[tuple[str, ...], ...] = (("history",), ("speeds", "curvatures"))
HISTORY_KEYS = ("history", "speeds", "curvatures")
CHAINS = ("independent", "conversation")
ANSWER_FORMATS = ("text", "structured")
VARIANTS = (
    "structured",
    "conversation",
    "conversation+structured",
    "no-history",
    "no-history+structured",
    "conversation+no-history",
    "conversation+no-history+structured",
)
# placeholders each stage must carry in a conversation variant: the earlier stages' texts are turns, not pasted
CONVERSATION_PLACEHOLDERS: dict[str, tuple[str, ...]] = {"scene": (), "intent": ("history",), "actions": ()}


def variant_name(chain: str = "independent", answer_format: str = "text", inputs: str = "full") -> str | None:
    """The prompt-set variant a run with ``chain``, ``answer_format`` and ``inputs`` uses (None: the paper's stages).

    Only ``inputs="no-history"`` changes the prompts; the image ablations send the paper's (or the
    request variant's) templates.
    """
    from lightemma.inputs import check_inputs

    if chain not in CHAINS:
        raise InputError(f"chain must be one of {', '.join(CHAINS)}, got {chain!r}")
    if answer_format not in ANSWER_FORMATS:
        raise InputError(f"answer format must be one of {', '.join(ANSWER_FORMATS)}, got {answer_format!r}")
    check_inputs(inputs)
    parts = [
        p
        for p, on in (
            ("conversation", chain == "conversation"),
            ("no-history", inputs == "no-history"),
            ("structured", answer_format == "structured"),
        )
        if on
    ]
    return "+".join(parts) or None


def _history_left(stages: dict[str, str]) -> list[str]:
    """The stages whose templates hold a history placeholder."""
    return [s for s, t in stages.items() if any("{" + k + "}" in t for k in HISTORY_KEYS)]


def content_hash(data: dict[str, Any]) -> str:
    """``sha256:<hex>`` of the canonical JSON (sorted keys, no spaces) of a prompt set's content."""
    canonical = json.dumps(data, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    return "sha256:" + hashlib.sha256(canonical.encode("utf-8")).hexdigest()


def _check_placeholders(origin: str, where: str, stages: dict[str, str], required: dict[str, tuple[str, ...]]) -> None:
    """Raise a :class:`UserError` naming the first template of ``stages`` that lacks a required placeholder."""
    for stage, template in stages.items():
        needed = required[stage]
        absent = [p for p in needed if p != "history" and "{" + p + "}" not in template]
        if "history" in needed and not any(all("{" + p + "}" in template for p in form) for form in HISTORY_FORMS):
            absent.append("history")
        if absent:
            names = ", ".join(
                "{history} (or {speeds} and {curvatures})" if p == "history" else "{" + p + "}" for p in absent
            )
            raise UserError(f"{origin}: the {where}{stage!r} template lacks placeholder(s) {names}")


def _variants(data: dict[str, Any], origin: str) -> dict[str, dict[str, str]]:
    """The ``variants`` object of a prompt set's content, validated (empty when absent)."""
    variants = data.get("variants", {})
    if not isinstance(variants, dict):
        raise UserError(f"{origin}: 'variants' must be an object of {', '.join(VARIANTS)}")
    for name, stages in variants.items():
        if name not in VARIANTS:
            raise UserError(f"{origin}: unknown variant {name!r} (known: {', '.join(VARIANTS)})")
        if (
            not isinstance(stages, dict)
            or not stages
            or any(s not in STAGES or not isinstance(t, str) for s, t in stages.items())
        ):
            raise UserError(
                f"{origin}: variant {name!r} must map stage names ({', '.join(STAGES)}) to template strings"
            )
        required = CONVERSATION_PLACEHOLDERS if name.startswith("conversation") else PLACEHOLDERS
        if "no-history" in name.split("+"):
            left = _history_left(stages)
            if left:
                raise UserError(
                    f"{origin}: the {name} variant's {left[0]!r} template holds a history placeholder "
                    "({history}, {speeds} or {curvatures}); a no-history template must not"
                )
            required = {s: tuple(p for p in req if p != "history") for s, req in required.items()}
        _check_placeholders(origin, f"{name} variant's ", stages, required)
    return {name: dict(stages) for name, stages in variants.items()}


@dataclass(frozen=True)
class PromptSet:
    """A named, hashed set of stage templates (with the variants' templates, if any).

    ``stages`` are the templates a run uses: the paper's (``paper_stages``), or after
    :meth:`select` those of a variant in their place.
    """

    name: str
    description: str
    stages: dict[str, str]
    hash: str
    variants: dict[str, dict[str, str]] = field(default_factory=dict)
    variant: str | None = None  # the variant whose templates ``stages`` holds (None: the paper's)
    variant_hash: str | None = None  # content hash of that variant's templates
    paper_stages: dict[str, str] = field(default_factory=dict)

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, origin: str = "prompt set") -> PromptSet:
        """Validate ``data`` (the JSON content) and build the set; errors name ``origin``."""
        stages = data.get("stages")
        if not isinstance(data.get("name"), str) or not isinstance(stages, dict):
            raise UserError(f"{origin}: a prompt set needs a string 'name' and a 'stages' object")
        missing = [s for s in STAGES if not isinstance(stages.get(s), str)]
        if missing:
            raise UserError(f"{origin}: stage template(s) {', '.join(missing)} missing (need {', '.join(STAGES)})")
        _check_placeholders(origin, "", {s: stages[s] for s in STAGES}, PLACEHOLDERS)
        variants = _variants(data, origin)
        base = {
            k: v for k, v in data.items() if k != "variants"
        }  # the paper's chain: hashed as before variants existed
        return cls(
            name=data["name"],
            description=str(data.get("description", "")),
            stages=dict(stages),
            hash=content_hash(base),
            variants=variants,
            paper_stages=dict(stages),
        )

    def select(self, chain: str = "independent", answer_format: str = "text", inputs: str = "full") -> PromptSet:
        """This set as a run with ``chain``, ``answer_format`` and ``inputs`` uses it: the variant's templates in place.

        Raises :class:`UserError` when the set has no templates for that variant, or when a
        no-history variant leaves a stage of the paper's with the history in place.
        """
        name = variant_name(chain, answer_format, inputs)
        paper = dict(self.paper_stages or self.stages)
        if name is None:
            return replace(self, stages=paper, variant=None, variant_hash=None, paper_stages=paper)
        if name not in self.variants:
            flags = " and ".join(
                f
                for f, on in (
                    ("--chain conversation", chain == "conversation"),
                    ("--inputs no-history", inputs == "no-history"),
                    ("--answer-format structured", answer_format == "structured"),
                )
                if on
            )
            raise UserError(
                f"prompt set {self.name!r} has no {name!r} variant, which {flags} needs; add its templates "
                'under "variants" (docs/run.md, Prompt sets)'
            )
        stages = {**paper, **self.variants[name]}
        left = _history_left(stages) if inputs == "no-history" else []
        if left:
            raise UserError(
                f"prompt set {self.name!r}: its {name!r} variant has no {left[0]!r} template, so that stage "
                "would keep the history; give every stage that holds the history a template there"
            )
        return replace(
            self, stages=stages, variant=name, variant_hash=content_hash(self.variants[name]), paper_stages=paper
        )

    def render(
        self,
        stage: str,
        *,
        scene: str = "",
        history: str = "",
        intent: str = "",
        speeds: str = "",
        curvatures: str = "",
    ) -> str:
        """The text of ``stage`` with the earlier stages' texts and the history filled in.

        ``history``, ``speeds`` and ``curvatures`` are the renderings of
        :func:`lightemma.frames.history_placeholders`.
        Each placeholder of the template is substituted once, in one pass over the template: a value (a
        model's scene or intent text) is data, so a ``{intent}`` or ``{history}`` inside it stays as written.
        """
        values = {"scene": scene, "history": history, "intent": intent, "speeds": speeds, "curvatures": curvatures}
        keys = [k for k in PLACEHOLDERS[stage] if k != "history"] + (
            list(HISTORY_KEYS) if "history" in PLACEHOLDERS[stage] else []
        )
        if not keys:
            return self.stages[stage]
        pattern = re.compile("|".join(re.escape("{" + k + "}") for k in keys))
        return pattern.sub(lambda m: values[m.group(0)[1:-1]].strip(), self.stages[stage])

    def describe(self) -> dict[str, str]:
        """What a run manifest records about the prompt set (and the variant in use, if any)."""
        out = {"name": self.name, "hash": self.hash}
        if self.variant is not None:
            out.update(variant=self.variant, variant_hash=str(self.variant_hash))
        return out


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
    if without_lone_surrogates(data) != data:
        raise UserError(
            f"{origin}: holds a lone surrogate (an escape such as \\ud83d, half of an emoji), which no request "
            "can carry; fix the file"
        )
    return PromptSet.from_dict(data, origin=origin)
