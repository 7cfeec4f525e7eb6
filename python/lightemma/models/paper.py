"""The paper's Tables I and II (``paper/lightemma-paper.tex``) as data, for ``--with-paper`` and the estimates.

Values are copied from the .tex; ``None`` stands for the paper's "-" and
``anomalous`` lists the cells the paper marks with a dagger (Section IV-B).
The paper scores 3,908 v1.0-test frames with the ``lightemma`` convention.

Leaf data: this module imports nothing of lightemma. A row's family is the prefix of its name as the paper writes it
(:data:`FAMILY_PREFIXES`; tests/unit/models/test_registry.py checks it equals the catalog's family of the same model). Matching a
run's model string to a paper row: :mod:`lightemma.models.names`.
"""

from __future__ import annotations

from typing import Any

PAPER_FRAMES = 3908
PAPER_CONVENTION = "lightemma"

# model: (time s, cost cents, input tokens, output tokens, H100 GPUs)
_TABLE_I: dict[str, tuple[float, float | None, int, int, int | None]] = {
    "GPT-4o": (12.1, 1.40, 4402, 341, None),
    "GPT-5.0": (15.3, 0.93, 3922, 440, None),
    "GPT-5.2": (11.6, 1.68, 6375, 400, None),
    "Claude-3.7-Sonnet": (14.8, 2.47, 5948, 461, None),
    "Claude-4.0-Sonnet": (17.0, 2.63, 6074, 540, None),
    "Claude-4.6-Sonnet": (22.2, 2.76, 6238, 660, None),
    "Gemini-2.0-Flash": (4.5, 0.07, 6398, 272, None),
    "Gemini-2.5-Flash": (28.5, 1.35, 1968, 402, None),
    "Gemini-3.0-Flash": (31.0, 0.35, 4484, 404, None),
    "Qwen-2.0-VL-7B": (9.1, None, 6593, 341, 1),
    "Qwen-2.5-VL-7B": (8.8, None, 6554, 318, 1),
    "Qwen-3.0-VL-8B": (12.8, None, 5359, 375, 1),
    "LLaMA-3.2-11B": (7.5, None, 1039, 313, 1),
    "LLaMA-3.2-90B": (40.8, None, 1078, 357, 3),
    "LLaMA-4.0-17B-Scout": (44.6, None, 1311, 546, 3),
}

# model: (FE %, FE corr %, ADE 1s, ADE 2s, ADE 3s, ADE avg, FDE)
_TABLE_II: dict[str, tuple[float, float, float, float, float, float, float]] = {
    "GPT-4o": (7.78, 0.08, 0.28, 0.92, 2.01, 1.07, 2.34),
    "GPT-5.0": (0.0, 0.0, 0.28, 0.92, 2.03, 1.07, 2.36),
    "GPT-5.2": (0.0, 0.0, 0.30, 1.02, 2.19, 1.17, 2.54),
    "Claude-3.7-Sonnet": (0.0, 0.0, 0.28, 0.94, 2.04, 1.08, 2.36),
    "Claude-4.0-Sonnet": (0.03, 0.0, 0.30, 1.07, 2.39, 1.25, 2.78),
    "Claude-4.6-Sonnet": (0.56, 0.0, 0.35, 1.25, 2.73, 1.44, 3.17),
    "Gemini-2.0-Flash": (0.7, 0.0, 0.31, 1.08, 2.36, 1.25, 2.79),
    "Gemini-2.5-Flash": (0.03, 0.0, 0.37, 1.32, 2.93, 1.54, 3.42),
    "Gemini-3.0-Flash": (0.0, 0.0, 0.28, 0.93, 2.08, 1.10, 2.44),
    "Qwen-2.0-VL-7B": (0.03, 0.03, 0.64, 1.61, 2.83, 1.69, 3.16),
    "Qwen-2.5-VL-7B": (0.0, 0.0, 0.47, 1.33, 2.55, 1.45, 2.90),
    "Qwen-3.0-VL-8B": (1.25, 0.0, 0.38, 1.09, 2.16, 1.21, 2.49),
    "LLaMA-3.2-11B": (0.69, 0.03, 0.52, 1.42, 2.67, 1.53, 3.03),
    "LLaMA-3.2-90B": (0.0, 0.0, 0.35, 1.15, 2.46, 1.32, 2.86),
    "LLaMA-4.0-17B-Scout": (0.05, 0.0, 0.29, 1.06, 2.40, 1.25, 2.81),
}

ANOMALOUS: dict[str, tuple[str, ...]] = {
    "Gemini-2.5-Flash": ("cost_cents_per_frame", "input_tokens"),
    "LLaMA-3.2-11B": ("input_tokens",),
    "LLaMA-3.2-90B": ("input_tokens",),
    "LLaMA-4.0-17B-Scout": ("input_tokens",),
}


#: (name prefix, family) of the paper's rows, in the paper's family order
FAMILY_PREFIXES: tuple[tuple[str, str], ...] = (
    ("GPT-", "GPT"),
    ("Claude-", "Claude"),
    ("Gemini-", "Gemini"),
    ("Qwen-", "Qwen"),
    ("LLaMA-", "LLaMA"),
)


def _family(model: str) -> str:
    """The family of a paper row's model name; ValueError for a name with none of :data:`FAMILY_PREFIXES`."""
    for prefix, family in FAMILY_PREFIXES:
        if model.startswith(prefix):
            return family
    raise ValueError(f"paper row {model!r} has no known family prefix")


def paper_efficiency_rows() -> list[dict[str, Any]]:
    """Table I as rows shaped like :meth:`Evaluation.efficiency_rows` (source ``paper``)."""
    return [
        {
            "model": model,
            "family": _family(model),
            "frames": PAPER_FRAMES,
            "seconds_per_frame": t,
            "cost_cents_per_frame": cost,
            "input_tokens": float(inp),
            "output_tokens": float(out),
            "gpus": gpus,
            "source": "paper",
            "anomalous": list(ANOMALOUS.get(model, ())),
        }
        for model, (t, cost, inp, out, gpus) in _TABLE_I.items()
    ]


def paper_accuracy_rows() -> list[dict[str, Any]]:
    """Table II as rows shaped like :meth:`Evaluation.accuracy_rows` (``lightemma`` convention)."""
    return [
        {
            "model": model,
            "family": _family(model),
            "convention": PAPER_CONVENTION,
            "frames": PAPER_FRAMES,
            "fe_pct": fe,
            "fe_corr_pct": fe_corr,
            "ade_1s": a1,
            "ade_2s": a2,
            "ade_3s": a3,
            "ade_avg": avg,
            "fde": fde,
            "miss_rate": None,
            "parse": "paper",
            "source": "paper",
        }
        for model, (fe, fe_corr, a1, a2, a3, avg, fde) in _TABLE_II.items()
    ]


ACCURACY_DIFF_KEYS: tuple[str, ...] = ("fe_pct", "fe_corr_pct", "ade_1s", "ade_2s", "ade_3s", "ade_avg", "fde")
EFFICIENCY_DIFF_KEYS: tuple[str, ...] = ("seconds_per_frame", "cost_cents_per_frame", "input_tokens", "output_tokens")
DIFF_LABEL = "Δ vs paper"
