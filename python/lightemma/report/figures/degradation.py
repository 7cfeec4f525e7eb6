"""The robustness figure: per corruption, the paired degradation (variant − clean) by severity, a panel per metric."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from lightemma.report.figures._mpl import pyplot


def robustness_figure(rows: Sequence[Mapping[str, Any]], metrics: Sequence[Any]) -> Any:
    """Degradation by severity per corruption: rows of :func:`~lightemma.evaluation.robustness.evaluate_robustness`
    whose variant is ``corrupt:NAME@S``; per metric (``metrics``: its ``key``, ``title``, ``unit``, ``lower_is_better``)
    one panel, x = severity 1–5, y = mean paired difference variant − clean with its 95 % scene-bootstrap interval,
    one line per corruption (per sweep's model where several sweeps are shown); a filled marker is significant after
    Holm's adjustment, a hollow one is not. ValueError when no row is a corruption."""
    plt = pyplot()
    corrupted = [r for r in rows if r.get("corruption") and r.get("severity")]
    if not corrupted:
        raise ValueError("no corruption variant to draw")
    shown = [m for m in metrics if any(r.get(f"{m.key}_diff") is not None for r in corrupted)]
    fig, axes = plt.subplots(1, len(shown), figsize=(4.6 * len(shown), 3.6), squeeze=False)
    lines: dict[tuple[str, str], list[Mapping[str, Any]]] = {}
    for r in corrupted:
        lines.setdefault((str(r.get("clean")), str(r["corruption"])), []).append(r)
    several = len({clean for clean, _ in lines}) > 1
    for ax, metric in zip(axes[0], shown, strict=False):
        for n, ((clean, name), members) in enumerate(sorted(lines.items())):
            members = sorted(members, key=lambda r: r["severity"])
            xs = [r["severity"] for r in members if r.get(f"{metric.key}_diff") is not None]
            ys = [r[f"{metric.key}_diff"] for r in members if r.get(f"{metric.key}_diff") is not None]
            if not xs:
                continue
            color = f"C{n % 10}"
            ax.plot(xs, ys, "-", color=color, label=f"{name}" + (f" ({clean})" if several else ""), zorder=2)
            for r in members:
                value = r.get(f"{metric.key}_diff")
                if value is None:
                    continue
                ci = r.get(f"{metric.key}_ci95")
                err = [[value - ci[0]], [ci[1] - value]] if ci else None
                filled = bool(r.get(f"{metric.key}_significant"))
                ax.errorbar(
                    [r["severity"]],
                    [value],
                    yerr=err,
                    fmt="o",
                    color=color,
                    capsize=3,
                    markerfacecolor=color if filled else "white",
                    zorder=3,
                )
        ax.axhline(0.0, color="0.3", linewidth=1.0, zorder=1)
        ax.set_xticks([1, 2, 3, 4, 5])
        ax.set_xlim(0.5, 5.5)
        ax.set_xlabel("severity")
        unit = f" ({metric.unit})" if metric.unit and metric.unit != "share" else ""
        worse = "higher is worse" if metric.lower_is_better else "lower is worse"
        ax.set_ylabel(f"{metric.title}{unit}: corrupted − clean")
        ax.set_title(f"{metric.title} ({worse})", fontsize=10)
    axes[0][0].legend(fontsize=7, loc="best")
    fig.tight_layout()
    return fig
