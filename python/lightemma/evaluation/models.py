"""Model names, families and generation order (SPEC §7), for labels and the bubble chart.

A run's manifest may carry ``display_name`` and ``family``; otherwise the paper's
models are recognised from their API / checkpoint ids, and anything else gets a
family inferred from the model string (``baseline:`` → Baseline, else Other).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

# families in the order the paper lists them; Baseline and Other come last
FAMILIES: tuple[str, ...] = ("GPT", "Claude", "Gemini", "Qwen", "LLaMA", "Baseline", "Other")


@dataclass(frozen=True)
class KnownModel:
    """One of the paper's fifteen models: display name, family, generation (1..3) and id pattern."""

    display_name: str
    family: str
    generation: int
    pattern: str  # regex on the normalised model string (see _normalise)


PAPER_MODELS: tuple[KnownModel, ...] = (
    KnownModel("GPT-4o", "GPT", 1, r"gpt-4o"),
    KnownModel("GPT-5.0", "GPT", 2, r"gpt-5(-0)?(?![-\d]*\d)"),
    KnownModel("GPT-5.2", "GPT", 3, r"gpt-5-2"),
    KnownModel("Claude-3.7-Sonnet", "Claude", 1, r"claude-3-7|3-7-sonnet"),
    KnownModel("Claude-4.0-Sonnet", "Claude", 2, r"claude-sonnet-4(-0)?(?!-?\d)|claude-4(-0)?-sonnet"),
    KnownModel("Claude-4.6-Sonnet", "Claude", 3, r"claude-sonnet-4-6|claude-4-6-sonnet"),
    KnownModel("Gemini-2.0-Flash", "Gemini", 1, r"gemini-2-0-flash"),
    KnownModel("Gemini-2.5-Flash", "Gemini", 2, r"gemini-2-5-flash"),
    KnownModel("Gemini-3.0-Flash", "Gemini", 3, r"gemini-3(-0)?-flash"),
    KnownModel("Qwen-2.0-VL-7B", "Qwen", 1, r"qwen-?2(-0)?-vl-7b"),
    KnownModel("Qwen-2.5-VL-7B", "Qwen", 2, r"qwen-?2-5-vl-7b"),
    KnownModel("Qwen-3.0-VL-8B", "Qwen", 3, r"qwen-?3(-0)?-vl-8b"),
    KnownModel("LLaMA-3.2-11B", "LLaMA", 1, r"llama-3-2-11b"),
    KnownModel("LLaMA-3.2-90B", "LLaMA", 2, r"llama-3-2-90b"),
    KnownModel("LLaMA-4.0-17B-Scout", "LLaMA", 3, r"llama-4(-0)?-(17b-)?scout"),
)

_FAMILY_HINTS = (("baseline:", "Baseline"), ("gpt", "GPT"), ("claude", "Claude"), ("gemini", "Gemini"), ("qwen", "Qwen"), ("llama", "LLaMA"))


def _normalise(model: str) -> str:
    return re.sub(r"[._\s/:]+", "-", model.lower())


def known_model(model: str) -> KnownModel | None:
    """The paper model a model string names (``openai/gpt-4o`` → GPT-4o), or None."""
    text = _normalise(model)
    for known in PAPER_MODELS:
        if re.search(known.pattern, text):
            return known
    return None


def infer_family(model: str) -> str:
    """Family from a model string: gpt→GPT, claude→Claude, …, ``baseline:``→Baseline, else Other."""
    lowered = model.lower()
    for hint, family in _FAMILY_HINTS:
        if hint in lowered:
            return family
    return "Other"


def family_rank(family: str) -> int:
    """Sort key of a family: the paper's order, then Baseline, Other, then unknown names."""
    return FAMILIES.index(family) if family in FAMILIES else len(FAMILIES)
