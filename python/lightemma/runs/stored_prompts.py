"""The prompts an imported run stores: shared text once per run, each frame's own part per frame.

The reference scripts build each stage's prompt from one fixed text, filled in with the frame's
own scene description (stages 2 and 3), driving intent (stage 3) and history of (speed, curvature)
— the chain of the paper's "VLM Prompting". Stored whole in every record, a prompt repeats the
fixed text and the frame's own stage answers (which the record holds anyway): most of a record's
bytes. An import therefore stores, per stage, a few **templates** in the run's manifest
(``prompt_set.templates``: format strings with the fields ``{scene}``, ``{intent}`` and ``{fill}``,
literal braces doubled) and, per call, the template's index and the frame's **fill**: the call's
prompt is ``templates[stage][prompt_template].format(scene=S, intent=I, fill=prompt_fill)``, where
S and I are the frame's stage-1 and stage-2 texts as the reference had them (a call's ``text``, or
its ``error_message`` when the reference's call failed). :func:`call_prompt` does this.

Exactness: a prompt is matched against a template by reading the decoding backwards (the
template's literal text and the frame's own texts, each at its place, from both ends), so a fill
found always decodes to the prompt; a template is decoded once more when it is made; and a prompt
that fits no template is stored whole in ``prompt``, as before. Templates are inferred while
importing: two frames' prompts (with the frame's own texts marked) give the text they share at the
start and at the end; what lies between is each frame's fill (in the reference runs: the history
numbers). At most :data:`MAX_TEMPLATES` per stage.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

#: markers standing for the frame's own stage texts inside a template while importing (never stored)
_MARK = {"scene": "\ue000", "intent": "\ue001"}
_SCENE, _INTENT = _MARK["scene"], _MARK["intent"]
_NAME = {mark: name for name, mark in _MARK.items()}
#: a stage text shorter than this is never looked for in a prompt (a short word could be anywhere)
MIN_REFERENCED = 16
#: templates per stage at most; prompts fitting none are stored whole
MAX_TEMPLATES = 16
#: a template is kept only when the two prompts it comes from share at least this share of the longer one
MIN_SHARED = 0.3
#: characters a template's head never ends with, nor its tail begins with (numbers go to the fill whole)
_NUMBER_CHARS = "0123456789.-+"


def _skeleton(prompt: str, texts: Mapping[str, str | None]) -> str | None:
    """``prompt`` with the first occurrence of each of the frame's own texts replaced by its marker; None when
    the prompt or a text holds a marker character (no template is then made from it)."""
    if _SCENE in prompt or _INTENT in prompt:
        return None
    out = prompt
    for name, mark in _MARK.items():
        text = texts.get(name)
        if not text or len(text) < MIN_REFERENCED:
            continue
        if _SCENE in text or _INTENT in text:
            return None
        at = out.find(text)
        if at >= 0:
            out = out[:at] + mark + out[at + len(text) :]
    return out


Part = tuple[bool, str]  # (True, "scene" | "intent"): the frame's text; (False, text): literal text


def _parts(marked: str) -> tuple[Part, ...]:
    """A marked text as parts: literal pieces and references to the frame's texts."""
    out: list[Part] = []
    piece = []
    for ch in marked:
        name = _NAME.get(ch)
        if name is None:
            piece.append(ch)
            continue
        if piece:
            out.append((False, "".join(piece)))
            piece = []
        out.append((True, name))
    if piece:
        out.append((False, "".join(piece)))
    return tuple(out)


def _as_format(parts: Sequence[Part]) -> str:
    """Parts as a format string: literal braces doubled, references as ``{scene}`` / ``{intent}``."""
    return "".join("{" + value + "}" if ref else value.replace("{", "{{").replace("}", "}}") for ref, value in parts)


@dataclass(frozen=True)
class _Template:
    head: tuple[Part, ...]
    tail: tuple[Part, ...]

    def fill(self, prompt: str, texts: Mapping[str, str | None]) -> str | None:
        """The part of ``prompt`` between this template's head and tail, with the frame's own texts where the template
        names them; None when the prompt does not have that form. Matching is the decoding read backwards, so a fill
        found always decodes to ``prompt`` (no copy is made but the fill)."""
        start = 0
        for ref, value in self.head:
            piece = texts.get(value) if ref else value
            if piece is None or not prompt.startswith(piece, start):
                return None
            start += len(piece)
        end = len(prompt)
        for ref, value in reversed(self.tail):
            piece = texts.get(value) if ref else value
            if piece is None or end - len(piece) < start or not prompt.endswith(piece, start, end):
                return None
            end -= len(piece)
        return prompt[start:end]

    def as_format(self) -> str:
        return _as_format(self.head) + "{fill}" + _as_format(self.tail)


class PromptTemplates:
    """The templates of one imported run, built while its frames are read (see the module docstring)."""

    def __init__(self) -> None:
        self._templates: dict[str, list[_Template]] = {}
        self._unmatched: dict[str, str] = {}  # stage -> the last marked prompt that fitted no template

    def encode(self, stage: str, prompt: str | None, texts: Mapping[str, str | None]) -> dict[str, Any]:
        """The fields of a call record that store ``prompt``: ``{"prompt": prompt}`` (whole), or ``{"prompt": None,
        "prompt_template": i, "prompt_fill": fill}``. ``texts``: the frame's ``scene`` and ``intent`` texts."""
        if not prompt:
            return {"prompt": prompt}
        templates = self._templates.setdefault(stage, [])
        for index, template in enumerate(templates):
            fill = template.fill(prompt, texts)
            if fill is not None:
                return {"prompt": None, "prompt_template": index, "prompt_fill": fill}
        marked = _skeleton(prompt, texts) if len(templates) < MAX_TEMPLATES else None
        if marked is None:
            return {"prompt": prompt}
        other = self._unmatched.get(stage)
        self._unmatched[stage] = marked
        ends = _common_ends(other, marked) if other is not None else None
        if ends is None:
            return {"prompt": prompt}
        template = _Template(_parts(ends[0]), _parts(ends[1]))
        fill = template.fill(prompt, texts)
        if fill is None or _render(template.as_format(), texts, fill) != prompt:  # a reference the two do not share
            return {"prompt": prompt}
        del self._unmatched[stage]
        templates.append(template)
        return {"prompt": None, "prompt_template": len(templates) - 1, "prompt_fill": fill}

    def to_manifest(self) -> dict[str, list[str]]:
        """Each stage's templates as format strings (``{scene}``, ``{intent}``, ``{fill}``), for the manifest."""
        return {stage: [t.as_format() for t in templates] for stage, templates in self._templates.items() if templates}


def _common_length(a: str, b: str, limit: int, *, suffix: bool = False) -> int:
    """How many characters ``a`` and ``b`` share at the start (or the end), at most ``limit``: a binary search over
    slice comparisons (memcmp), not a loop over characters."""
    lo, hi = 0, limit
    while lo < hi:
        mid = (lo + hi + 1) // 2
        same = a[len(a) - mid :] == b[len(b) - mid :] if suffix else a[:mid] == b[:mid]
        lo, hi = (mid, hi) if same else (lo, mid - 1)
    return lo


def _common_ends(a: str, b: str) -> tuple[str, str] | None:
    """(head, tail): the longest start and end ``a`` and ``b`` share (not overlapping, a number never cut), or None
    when they share less than :data:`MIN_SHARED` of the longer text."""
    limit = min(len(a), len(b))
    n = _common_length(a, b, limit)
    if _in_number(a, n) or _in_number(b, n):  # the prompts part inside a number: it goes to the fill whole
        while n and a[n - 1] in _NUMBER_CHARS:
            n -= 1
    m = _common_length(a, b, limit - n, suffix=True)
    if _in_number(a, len(a) - m) or _in_number(b, len(b) - m):
        while m and a[len(a) - m] in _NUMBER_CHARS:
            m -= 1
    if n + m < MIN_SHARED * max(len(a), len(b)):  # of the longer: a short prompt and a long one are two forms
        return None
    return a[:n], a[len(a) - m :] if m else ""


def _in_number(text: str, at: int) -> bool:
    """Whether ``text`` is cut inside a number at ``at`` (number characters on both sides)."""
    return 0 < at < len(text) and text[at - 1] in _NUMBER_CHARS and text[at] in _NUMBER_CHARS


def call_prompt(
    call: Mapping[str, Any], texts: Mapping[str, str | None], templates: Mapping[str, Sequence[str]] | None
) -> str | None:
    """The prompt a stored call was sent: its ``prompt``, or its template (from the run manifest's
    ``prompt_set.templates``) filled with the frame's ``scene`` / ``intent`` texts and the call's ``prompt_fill``.

    None when the call stores no prompt, or names a template the manifest does not hold.
    """
    prompt = call.get("prompt")
    if isinstance(prompt, str) or "prompt_template" not in call:
        return prompt if isinstance(prompt, str) else None
    stage_templates = (templates or {}).get(call.get("stage"))  # type: ignore[arg-type]  # any other stage: None
    index, fill = call.get("prompt_template"), call.get("prompt_fill")
    if (
        not isinstance(stage_templates, Sequence)
        or type(index) is not int
        or not 0 <= index < len(stage_templates)
        or not isinstance(fill, str)
        or not isinstance(stage_templates[index], str)
    ):
        return None
    try:
        return _render(stage_templates[index], texts, fill)
    except (ValueError, KeyError, IndexError):  # a hand-edited template
        return None


def _render(template: str, texts: Mapping[str, str | None], fill: str) -> str:
    """A template filled with the frame's texts and a call's fill: the one decoding, for writers and readers."""
    return template.format_map({"scene": texts.get("scene") or "", "intent": texts.get("intent") or "", "fill": fill})


def frame_texts(calls: Sequence[Mapping[str, Any]]) -> dict[str, str | None]:
    """The ``scene`` and ``intent`` texts a prompt's template refers to, from a record's calls: each stage's text,
    or the reference's own text of a failed call (``error_message``)."""
    out: dict[str, str | None] = {"scene": None, "intent": None}
    for call in calls:
        stage = call.get("stage") if isinstance(call, Mapping) else None
        if stage in out:
            text = call.get("text")
            out[stage] = (
                text
                if isinstance(text, str)
                else (call.get("error_message") if isinstance(call.get("error_message"), str) else None)
            )
    return out
