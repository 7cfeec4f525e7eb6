"""The robustness tables (``evaluate`` / ``report`` of a sweep) and the report's robustness section.

Rows come from :func:`lightemma.evaluation.robustness.evaluate_robustness` (``Evaluation.robustness``).
"""

from __future__ import annotations

from typing import Any

from lightemma.report.figures.degradation import robustness_figure
from lightemma.report.tables import Column, Table, fixed

#: the tables of this module, by name
ROBUSTNESS_TABLES = ("robustness", "visual_reliance")


def _significant(value: object) -> str:
    return "-" if value is None else ("yes" if value else "no")


def _metric_columns(metric: Any) -> list[Column]:
    unit = f" ({metric.unit})" if metric.unit and metric.unit != "share" else ""
    digits = 3 if metric.key == "ade_avg" else 4
    return [
        Column(f"{metric.key}_clean", f"{metric.title} clean{unit}", fixed(digits)),
        Column(f"{metric.key}_variant", f"{metric.title} variant{unit}", fixed(digits)),
        Column(
            f"{metric.key}_diff",
            f"{metric.title} variant − clean{unit} [95% CI]",
            fixed(digits),
            ci=f"{metric.key}_ci95",
        ),
        Column(f"{metric.key}_p_holm", f"{metric.title} p (Holm)", fixed(4)),
        Column(f"{metric.key}_significant", f"{metric.title} significant", _significant),
    ]


def _paired_note(evaluation: Any, rows: int) -> str:
    r = evaluation.resampling
    return (
        f"Paired with the sweep's clean run on the frames with a value in both; {100 * r.confidence:g} % "
        "scene-bootstrap "
        f"interval of the mean difference; p from {r.n_resamples} sign flips of scene-level differences; Holm family: "
        f"the {rows} row(s) of the robustness table, per metric; significant: p (Holm) ≤ {1 - r.confidence:.2f}."
    )


def robustness_table(evaluation: Any) -> Table:
    """Each sweep variant against its clean run: ADE avg, off-road, collision and the planning score where evaluated."""
    result = evaluation.robustness
    columns = [
        Column("model", "Variant run"),
        Column("variant", "Variant"),
        Column("frames", "Common frames"),
        Column("scenes", "Scenes"),
    ]
    for metric in result.metrics:
        columns += _metric_columns(metric)
    names = ", ".join(f"{m.title}: {m.id}" for m in result.metrics)
    notes = [
        "variant − clean > 0 is worse for ADE, off-road and collision; < 0 is worse for the planning score. clean: the "
        "paper's inputs; no-image, blank-image, no-history: the ablations; corrupt:NAME@S: the image corrupted at "
        "severity S; history-noise / history-stale: a perturbed history (docs/definitions.md#robustness-sweeps).",
        f"Metrics: {names}.",
        _paired_note(evaluation, len(result.rows)),
    ]
    return Table(
        f"Robustness — each variant paired with its sweep's clean run, {evaluation.main_convention} convention",
        columns,
        list(result.rows),
        name="robustness",
        notes=notes,
    )


def visual_reliance_table(evaluation: Any) -> Table:
    """Clean vs no-image vs blank-image: how much of the clean run's ADE the image is worth."""
    result = evaluation.robustness
    columns = [
        Column("clean", "Clean run"),
        Column("variant", "Without the image"),
        Column("frames", "Common frames"),
        Column("ade_avg_clean", "ADE avg clean (m)", fixed(3)),
        Column("ade_avg_variant", "ADE avg without (m)", fixed(3)),
        Column("ade_avg_diff", "without − clean (m) [95% CI]", fixed(3), ci="ade_avg_ci95"),
        Column("ade_avg_p_holm", "p (Holm)", fixed(4)),
        Column("ade_avg_significant", "significant", _significant),
        Column("reliance_pct", "Visual reliance (% of clean ADE)", fixed(1)),
    ]
    notes = [
        "Visual reliance = 100 · (ADE avg without the image − clean) / clean, on the same frames: > 0, the model "
        "drives "
        "worse without the image (it uses it); ≈ 0, it drives from the text alone. no-image sends no image; "
        "blank-image a uniform grey one of the same size (the same image tokens, no information). Intervals and p: "
        "the robustness table's rows."
    ]
    return Table(
        "Visual reliance — clean vs no-image vs blank-image",
        columns,
        list(result.reliance),
        name="visual_reliance",
        notes=notes,
    )


def robustness_tables(evaluation: Any) -> list[Table]:
    """The robustness table and the visual-reliance summary, where the evaluated runs hold a sweep with rows."""
    result = getattr(evaluation, "robustness", None)
    if result is None or not result.rows:
        return []
    tables = [robustness_table(evaluation)]
    if result.reliance:
        tables.append(visual_reliance_table(evaluation))
    return tables


def robustness_section(w: Any, tables: list[Table], evaluation: Any) -> None:
    """The report's "How robust is it?" section: the tables and the degradation-by-severity figure
    (``figures/robustness.png``) where the sweep holds corruptions."""
    shown = [t for t in tables if t.name in ROBUSTNESS_TABLES]
    if not shown:
        return
    w.lines += [
        "## How robust is it?",
        "",
        "Each variant of a sweep (`lightemma sweep`) paired with the sweep's clean run on the same frames "
        "(docs/definitions.md#robustness-sweeps).",
        "",
    ]
    for table in shown:
        w.table(table)
    result = evaluation.robustness
    if any(r.get("corruption") and r.get(f"{result.metrics[0].key}_diff") is not None for r in result.rows):
        w.figure(
            robustness_figure(result.rows, result.metrics),
            "robustness",
            "Degradation by severity per corruption: mean paired difference corrupted − clean with its 95 % "
            "scene-bootstrap interval, one panel per metric; filled: significant after Holm",
        )
