"""Model names, families and generation order (the paper's Table I), for labels and the bubble chart.

A run's manifest may carry ``display_name`` and ``family``; otherwise the paper's
models are recognised from their API / checkpoint ids, and anything else gets a
family inferred from the model string (``baseline:`` → Baseline, else Other).
"""

from __future__ import annotations

import re

from lightemma.registry import PAPER_MODELS, ModelInfo, lookup

# families in the order the paper lists them; Baseline and Other come last
FAMILIES: tuple[str, ...] = ("GPT", "Claude", "Gemini", "Qwen", "LLaMA", "Baseline", "Other")

# regex on the normalised model string (see _normalise) per registry key, so that
# provider ids in any spelling (``openai/gpt-4o``, ``Qwen/Qwen2.5-VL-7B-Instruct``) are recognised
_PATTERNS: dict[str, str] = {
    "gpt-4o": r"gpt-4o",
    "gpt-5.0": r"gpt-5(-0)?(?![-\d]*\d)",
    "gpt-5.2": r"gpt-5-2",
    "claude-3.7-sonnet": r"claude-3-7|3-7-sonnet",
    "claude-4.0-sonnet": r"claude-sonnet-4(-0)?(?!-?\d)|claude-4(-0)?-sonnet",
    "claude-4.6-sonnet": r"claude-sonnet-4-6|claude-4-6-sonnet",
    "gemini-2.0-flash": r"gemini-2-0-flash",
    "gemini-2.5-flash": r"gemini-2-5-flash",
    "gemini-3.0-flash": r"gemini-3(-0)?-flash",
    "qwen-2.0-vl-7b": r"qwen-?2(-0)?-vl-7b",
    "qwen-2.5-vl-7b": r"qwen-?2-5-vl-7b",
    "qwen-3.0-vl-8b": r"qwen-?3(-0)?-vl-8b",
    "llama-3.2-11b": r"llama-3-2-11b",
    "llama-3.2-90b": r"llama-3-2-90b",
    "llama-4.0-17b-scout": r"llama-4(-0)?-(17b-)?scout",
}

_FAMILY_HINTS = (("baseline:", "Baseline"), ("gpt", "GPT"), ("claude", "Claude"), ("gemini", "Gemini"), ("qwen", "Qwen"), ("llama", "LLaMA"))


def _normalise(model: str) -> str:
    return re.sub(r"[._\s/:]+", "-", model.lower())


def known_model(model: str) -> ModelInfo | None:
    """The registry entry of the paper model a model string names (``openai/gpt-4o`` → GPT-4o), or None.

    A registry key, display name or provider id is looked up as such; other
    spellings are matched against the id patterns.
    """
    found = lookup(model)
    if found in PAPER_MODELS:
        return found
    text = _normalise(model)
    for known in PAPER_MODELS:
        if re.search(_PATTERNS[known.key], text):
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
