"""The paper's Fig. 1: ADE avg per model, grouped by family in generation order, bubble
area proportional to time per frame, colour by family (one shade per model), with the
scene-bootstrap 95 % interval as a bar when known."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from lightemma.models.catalog import PAPER_MODELS
from lightemma.models.names import family_rank
from lightemma.models.paper import paper_accuracy_rows, paper_efficiency_rows
from lightemma.report.figures._mpl import FAMILY_COLORS, family_color, model_colors, pyplot
from lightemma.report.tables import coverage_note

MAX_AREA = 1800.0  # points² of the slowest model's bubble
MIN_AREA = 25.0


def _ordered(points: Sequence[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    indexed = list(enumerate(points))
    indexed.sort(key=lambda p: (family_rank(p[1].get("family", "Other")), p[1].get("generation") or 99, p[0]))
    return [p for _, p in indexed]


def bubble_chart(
    points: Sequence[Mapping[str, Any]], *, title: str | None = "ADE by model family and generation"
) -> Any:
    """Draw the bubble chart from dicts with ``model``, ``family``, ``ade_avg``, ``seconds_per_frame``
    (optional ``generation`` to order within a family, ``ade_avg_ci95`` [low, high] drawn as a bar,
    ``color``, ``note`` after the name, ``source="paper"`` for hollow reference bubbles).

    Points without an ADE are left out; the axis spans the points shown (scored frames only).
    Returns the matplotlib Figure.
    """
    plt = pyplot()
    shown = [p for p in _ordered(points) if p.get("ade_avg") is not None and math.isfinite(p["ade_avg"])]
    if not shown:
        raise ValueError("bubble chart: no model has an ADE to show")
    colors = model_colors(shown)
    seconds = [p.get("seconds_per_frame") or 0.0 for p in shown]
    slowest = max(max(seconds), 1e-9)
    slots: dict[
        str, list[tuple[Mapping[str, Any], float]]
    ] = {}  # a run and the paper's row of the same model share a slot
    for p, secs in zip(shown, seconds):
        slots.setdefault(str(p["model"]), []).append((p, secs))
    fig, ax = plt.subplots(figsize=(min(18.0, max(6.0, 0.72 * len(slots) + 2.5)), 5.2))
    xs: list[float] = []
    x = 0.0
    previous = None
    for members in slots.values():
        family = members[0][0].get("family")
        if previous is not None and family != previous:
            x += 0.8  # gap between families
        xs.append(x)
        previous = family
        x += 1.0
    for xpos, (label, members) in zip(xs, slots.items()):
        for p, secs in members:
            color = p.get("color") or colors[label]
            area = MIN_AREA + (MAX_AREA - MIN_AREA) * (secs / slowest)
            hollow = p.get("source") == "paper"
            ax.scatter(
                [xpos],
                [p["ade_avg"]],
                s=area,
                facecolors="none" if hollow else color,
                edgecolors=color,
                linewidths=1.6,
                alpha=0.8 if hollow else 0.7,
                zorder=4 if hollow else 3,
            )
            ci = _interval(p)
            if ci:
                ax.errorbar(
                    [xpos],
                    [p["ade_avg"]],
                    yerr=[[p["ade_avg"] - ci[0]], [ci[1] - p["ade_avg"]]],
                    color="0.15",
                    linewidth=1.1,
                    capsize=3,
                    zorder=5,
                )
            # the value: a run's above its interval (or bubble), the paper's inside its hollow bubble (or below a small one)
            radius = math.sqrt(area / math.pi)
            if hollow:
                inside = radius >= 11
                ax.annotate(
                    f"{p['ade_avg']:.2f}",
                    (xpos, p["ade_avg"]),
                    xytext=(0, 0 if inside else -radius - 2),
                    textcoords="offset points",
                    ha="center",
                    va="center" if inside else "top",
                    fontsize=7,
                    color="0.3",
                    style="italic",
                    zorder=6,
                    bbox={"boxstyle": "round,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.75},
                )
            else:
                top, lift = (ci[1], 2) if ci else (p["ade_avg"], radius + 2)
                ax.annotate(
                    f"{p['ade_avg']:.2f}",
                    (xpos, top),
                    xytext=(0, lift),
                    textcoords="offset points",
                    ha="center",
                    va="bottom",
                    fontsize=7,
                    fontweight="bold",
                    zorder=6,
                )
    ax.set_xticks(xs)
    ax.set_xticklabels(
        [
            label
            + (" (paper)" if all(p.get("source") == "paper" for p, _ in members) else "")
            + "".join(p.get("note") or "" for p, _ in members)
            for label, members in slots.items()
        ],
        rotation=40,
        ha="right",
        fontsize=8,
    )
    ades = [p["ade_avg"] for p in shown] + [v for p in shown for v in (_interval(p) or ())]
    span = max(ades) - min(ades)
    ax.set_ylim(max(0.0, min(ades) - 0.3 * span - 0.1), max(ades) + 0.3 * span + 0.1)
    ax.set_xlim(xs[0] - 0.9, xs[-1] + 0.9)
    ax.set_ylabel("ADE avg (m) — lower is better")
    ax.grid(axis="y", alpha=0.3)
    families = list(dict.fromkeys(p.get("family", "Other") for p in shown))

    def swatch(family: str) -> str:  # baselines and others have a colour per model: show the first one's
        if family == "Other" or family not in FAMILY_COLORS:
            return next(colors[str(p["model"])] for p in shown if p.get("family", "Other") == family)
        return family_color(family)

    handles = [plt.Line2D([], [], marker="o", linestyle="", color=swatch(f), markersize=8, label=f) for f in families]
    handles.append(plt.Line2D([], [], linestyle="", label=f"area: time/frame (largest {slowest:.1f} s)"))
    if any(p.get("source") == "paper" for p in shown):
        handles.append(
            plt.Line2D(
                [],
                [],
                marker="o",
                linestyle="",
                markerfacecolor="none",
                markeredgecolor="0.3",
                markersize=8,
                label="the paper's (value in italics)",
            )
        )
    if any(_interval(p) for p in shown):
        handles.append(plt.Line2D([], [], color="0.15", linewidth=1.2, label="95 % CI (scenes)"))
    ax.legend(handles=handles, fontsize=8, loc="upper left", ncol=min(5, len(handles)), framealpha=0.9)
    if title:
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return fig


def _interval(point: Mapping[str, Any]) -> list[float] | None:
    ci = point.get("ade_avg_ci95")
    if (
        isinstance(ci, (list, tuple))
        and len(ci) == 2
        and all(isinstance(v, (int, float)) and math.isfinite(v) for v in ci)
    ):
        return [float(ci[0]), float(ci[1])]
    return None


def bubble_points(evaluation: Any, *, convention: str = "lightemma", with_paper: bool = False) -> list[dict[str, Any]]:
    """Points for :func:`bubble_chart` from an :class:`~lightemma.evaluation.Evaluation` (scored frames only)."""
    points = [
        {
            "model": m.label,
            "family": m.family,
            "generation": m.generation,
            "ade_avg": m.metrics[convention]["ade_avg"],
            "ade_avg_ci95": m.intervals.get(convention, {}).get("ade_avg"),
            "seconds_per_frame": m.efficiency["seconds_per_frame"],
            "note": coverage_note(m.scored_pct) if m.low_coverage else "",
        }
        for m in evaluation.models
    ]
    if with_paper:
        times = {r["model"]: r["seconds_per_frame"] for r in paper_efficiency_rows()}
        generation = {k.display_name: k.generation for k in PAPER_MODELS}
        points += [
            {
                "model": r["model"],
                "family": r["family"],
                "generation": generation[r["model"]],
                "ade_avg": r["ade_avg"],
                "seconds_per_frame": times[r["model"]],
                "source": "paper",
            }
            for r in paper_accuracy_rows()
        ]
    return points
