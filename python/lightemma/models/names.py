"""Model-name matching: a run's model string → the catalog's paper model, its family, its paper row.

For labels, the bubble chart and ``--with-paper`` (:func:`beside_paper`).

A run's manifest may carry ``display_name`` and ``family``; otherwise the paper's
models are recognised from their API / checkpoint ids, and anything else gets a
family inferred from the model string (``baseline:`` → Baseline, else Other).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Any

from lightemma.models.catalog import PAPER_MODELS, ModelInfo, lookup
from lightemma.models.paper import DIFF_LABEL

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

_FAMILY_HINTS = (
    ("baseline:", "Baseline"),
    ("gpt", "GPT"),
    ("claude", "Claude"),
    ("gemini", "Gemini"),
    ("qwen", "Qwen"),
    ("llama", "LLaMA"),
)


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


def paper_model_name(model: str) -> str | None:
    """The paper's row name (display name) for a run's model string, via the catalog; None when not a paper model."""
    known = known_model(model) if not model.startswith("baseline:") else None
    return known.display_name if known is not None else None


def beside_paper(
    models: Sequence[Any], rows: list[dict[str, Any]], paper_rows: list[dict[str, Any]], keys: Sequence[str]
) -> list[dict[str, Any]]:
    """Each run's row followed by the paper's row of the same model and a row of differences (run − paper).

    ``models`` are the runs' :class:`~lightemma.evaluation.core.ModelResult` in
    the order of ``rows``. Rows of runs made on synthetic data are marked
    ``note: "synthetic data"``. Paper rows no run matched follow at the end, so
    the paper's table stays complete. Differences are None where either cell is.
    """
    paper = {row["model"]: row for row in paper_rows}
    used: set[str] = set()
    out: list[dict[str, Any]] = []
    for model, row in zip(models, rows):
        row = dict(row)
        if getattr(model, "dataset_kind", None) == "synthetic":
            row["note"] = "synthetic data"
        out.append(row)
        name = paper_model_name(model.model)
        if name is None or name not in paper:
            continue
        used.add(name)
        ref = paper[name]
        out.append(ref)
        diff: dict[str, Any] = {"model": DIFF_LABEL, "family": row.get("family"), "source": "diff"}
        for key in keys:
            a, b = row.get(key), ref.get(key)
            diff[key] = a - b if isinstance(a, (int, float)) and isinstance(b, (int, float)) else None
        out.append(diff)
    return out + [row for name, row in paper.items() if name not in used]
