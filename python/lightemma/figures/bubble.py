"""The paper's Fig. 1: ADE avg per model, grouped by family in generation order, bubble
area proportional to time per frame, colour by family."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from lightemma.evaluation.models import family_rank
from lightemma.figures._mpl import family_color, pyplot

MAX_AREA = 1800.0  # points² of the slowest model's bubble
MIN_AREA = 25.0


def _ordered(points: Sequence[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    indexed = list(enumerate(points))
    indexed.sort(key=lambda p: (family_rank(p[1].get("family", "Other")), p[1].get("generation") or 99, p[0]))
    return [p for _, p in indexed]


def bubble_chart(points: Sequence[Mapping[str, Any]], *, title: str | None = "ADE by model family and generation") -> Any:
    """Draw the bubble chart from dicts with ``model``, ``family``, ``ade_avg``, ``seconds_per_frame``
    (optional ``generation`` to order within a family, ``source="paper"`` for hollow reference bubbles).

    Points without an ADE are left out. Returns the matplotlib Figure.
    """
    plt = pyplot()
    shown = [p for p in _ordered(points) if p.get("ade_avg") is not None and math.isfinite(p["ade_avg"])]
    if not shown:
        raise ValueError("bubble chart: no model has an ADE to show")
    seconds = [p.get("seconds_per_frame") or 0.0 for p in shown]
    slowest = max(max(seconds), 1e-9)
    fig, ax = plt.subplots(figsize=(max(6.0, 0.75 * len(shown) + 2.5), 4.8))
    xs: list[float] = []
    x = 0.0
    previous = None
    for p in shown:
        if previous is not None and p.get("family") != previous:
            x += 0.8  # gap between families
        xs.append(x)
        previous = p.get("family")
        x += 1.0
    for xpos, p, secs in zip(xs, shown, seconds):
        color = family_color(p.get("family", "Other"))
        area = MIN_AREA + (MAX_AREA - MIN_AREA) * (secs / slowest)
        hollow = p.get("source") == "paper"
        ax.scatter([xpos], [p["ade_avg"]], s=area, facecolors="none" if hollow else color, edgecolors=color, linewidths=1.5, alpha=0.75, zorder=3)
        radius = math.sqrt(area / math.pi)  # points
        inside = radius >= 11  # small bubbles get their number above them
        ax.annotate(f"{p['ade_avg']:.2f}", (xpos, p["ade_avg"]), xytext=(0, 0 if inside else radius + 3), textcoords="offset points", ha="center", va="center" if inside else "bottom", fontsize=7, zorder=4)
    ax.set_xticks(xs)
    ax.set_xticklabels([str(p["model"]) + (" (paper)" if p.get("source") == "paper" else "") for p in shown], rotation=40, ha="right", fontsize=8)
    ades = [p["ade_avg"] for p in shown]
    span = max(ades) - min(ades)
    ax.set_ylim(max(0.0, min(ades) - 0.25 * span - 0.1), max(ades) + 0.25 * span + 0.1)
    ax.set_xlim(xs[0] - 0.8, xs[-1] + 0.8)
    ax.set_ylabel("ADE avg (m) — lower is better")
    ax.grid(axis="y", alpha=0.3)
    families = list(dict.fromkeys(p.get("family", "Other") for p in shown))
    handles = [plt.Line2D([], [], marker="o", linestyle="", color=family_color(f), markersize=8, label=f) for f in families]
    handles.append(plt.Line2D([], [], linestyle="", label=f"area ∝ time/frame (max {slowest:.1f} s)"))
    ax.legend(handles=handles, fontsize=8, loc="upper left", ncol=min(4, len(handles)))
    if title:
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return fig


def bubble_points(evaluation: Any, *, convention: str = "lightemma", with_paper: bool = False) -> list[dict[str, Any]]:
    """Points for :func:`bubble_chart` from an :class:`~lightemma.evaluation.Evaluation`."""
    points = [
        {
            "model": m.label,
            "family": m.family,
            "generation": m.generation,
            "ade_avg": m.metrics[convention]["ade_avg"],
            "seconds_per_frame": m.efficiency["seconds_per_frame"],
        }
        for m in evaluation.models
    ]
    if with_paper:
        from lightemma.registry import PAPER_MODELS
        from lightemma.evaluation.paper import paper_accuracy_rows, paper_efficiency_rows

        times = {r["model"]: r["seconds_per_frame"] for r in paper_efficiency_rows()}
        generation = {k.display_name: k.generation for k in PAPER_MODELS}
        points += [
            {"model": r["model"], "family": r["family"], "generation": generation[r["model"]], "ade_avg": r["ade_avg"], "seconds_per_frame": times[r["model"]], "source": "paper"}
            for r in paper_accuracy_rows()
        ]
    return points
