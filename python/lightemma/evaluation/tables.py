"""Build the paper's tables (Table I efficiency, Table II accuracy) from an :class:`Evaluation`,
plus the paired comparisons (``pairwise_ade``) and the per-family generation verdicts."""

from __future__ import annotations

from lightemma.evaluation.core import LOW_COVERAGE, Evaluation
from lightemma.evaluation.paper import (
    ACCURACY_DIFF_KEYS,
    EFFICIENCY_DIFF_KEYS,
    PAPER_CONVENTION,
    beside_paper,
    paper_accuracy_rows,
    paper_efficiency_rows,
)
from lightemma.tables import ACCURACY_COLUMNS, EFFICIENCY_COLUMNS, Column, Table, coverage_note, fixed


def coverage_flags(evaluation: Evaluation) -> dict[str, str]:
    """Model label -> the note every table prints after the name of a model with < 50 % scored frames."""
    return {m.label: coverage_note(m.scored_pct) for m in evaluation.models if m.low_coverage}


def _notes(evaluation: Evaluation, *, intervals: bool = False) -> list[str]:
    notes = []
    if coverage_flags(evaluation):
        notes.append(f"Flagged: fewer than {100 * LOW_COVERAGE:.0f} % of the model's frames were scored; its numbers describe only the frames it managed.")
    if intervals and evaluation.resampling.n_resamples:
        r = evaluation.resampling
        notes.append(
            f"Only scored frames enter a mean. [low, high]: {100 * r.confidence:g} % scene-level bootstrap interval "
            f"({r.n_resamples} resamples of scenes, seed {r.seed})."
        )
    return notes


def accuracy_table(evaluation: Evaluation, convention: str, *, with_paper: bool = False) -> Table:
    """Table II for one convention; with the paper, each run beside the paper's row of its model (``lightemma`` only)."""
    rows = evaluation.accuracy_rows(convention)
    scope = f"{evaluation.n_common} frames scored in every run" if evaluation.common else "each run's scored frames"
    title = f"Accuracy — {convention} convention ({scope})"
    if with_paper and convention == PAPER_CONVENTION:
        rows = beside_paper(evaluation.models, rows, paper_accuracy_rows(), ACCURACY_DIFF_KEYS)
    flags, notes = coverage_flags(evaluation), _notes(evaluation, intervals=True)
    for row in rows:
        if row.get("ci95_unavailable") and row.get("source") != "paper":
            # the row is computed; only its interval is missing, and the note says why
            flags[row["model"]] = flags.get(row["model"], "") + " (no interval)"
            notes.append(f"{row['model']}: {row['ci95_unavailable']}.")
    return Table(title, ACCURACY_COLUMNS, rows, name=f"accuracy_{convention}", flags=flags, notes=notes)


def efficiency_table(evaluation: Evaluation, *, with_paper: bool = False) -> Table:
    """Table I (time, cost, tokens, GPUs) plus run wall time and frames/s."""
    rows = evaluation.efficiency_rows()
    if with_paper:
        rows = beside_paper(evaluation.models, rows, paper_efficiency_rows(), EFFICIENCY_DIFF_KEYS)
    return Table("Efficiency — per frame, all attempts", EFFICIENCY_COLUMNS, rows, name="efficiency", flags=coverage_flags(evaluation), notes=_notes(evaluation))


PAIRWISE_COLUMNS: tuple[Column, ...] = (
    Column("model_a", "Model A"),
    Column("model_b", "Model B"),
    Column("frames", "Common frames"),
    Column("scenes", "Scenes"),
    Column("ade_avg_diff", "ADE avg A − B (m) [95% CI]", fixed(3), ci="ci95"),
    Column("p_value", "p", fixed(4)),
    Column("p_holm", "p (Holm)", fixed(4)),
    Column("significant", "Significant", lambda v: "-" if v is None else ("yes" if v else "no")),
)

GENERATION_COLUMNS: tuple[Column, ...] = (
    Column("family", "Family"),
    Column("model", "Model"),
    Column("predecessor", "Predecessor"),
    Column("change", "ADE avg change (m) [95% CI]", fixed(3), ci="ci95"),
    Column("p_holm", "p (Holm)", fixed(4)),
    Column("verdict", "Newer generation is"),
)


def pairwise_table(evaluation: Evaluation) -> Table:
    """Every pair of runs: mean paired ADE-avg difference on common frames, interval, p-values (``pairwise_ade``)."""
    r = evaluation.resampling
    notes = [
        f"A − B < 0: A is better. Paired on the frames scored in both runs; {100 * r.confidence:g} % scene-bootstrap interval; "
        f"p from {r.n_resamples} sign flips of scene-level differences; Holm-adjusted over all {len(evaluation.pairwise or [])} pairs; "
        f"significant: p (Holm) ≤ {1 - r.confidence:.2f}.",
        *_notes(evaluation)[:1],
    ]
    title = f"Paired comparisons — ADE avg, {evaluation.main_convention} convention"
    return Table(title, PAIRWISE_COLUMNS, list(evaluation.pairwise or []), name="pairwise_ade", flags=coverage_flags(evaluation), notes=notes)


def generations_table(evaluation: Evaluation) -> Table:
    """Per family, each generation against its predecessor: better, worse or not distinguishable."""
    notes = ["Change = newer − older (negative: the newer generation is better); a verdict needs p (Holm) ≤ "
             f"{1 - evaluation.resampling.confidence:.2f}, else not distinguishable.", *_notes(evaluation)[:1]]
    return Table("Generations — is each generation better than its predecessor?", GENERATION_COLUMNS, evaluation.generations(), name="generations", flags=coverage_flags(evaluation), notes=notes)


def evaluation_tables(evaluation: Evaluation, *, with_paper: bool = False) -> list[Table]:
    """Efficiency first (Table I), then accuracy per evaluated convention (Table II), then the paired comparisons if computed."""
    tables = [efficiency_table(evaluation, with_paper=with_paper)] + [accuracy_table(evaluation, c, with_paper=with_paper) for c in evaluation.conventions]
    if evaluation.pairwise:  # computed, and at least two runs
        tables.append(pairwise_table(evaluation))
        if evaluation.generations():
            tables.append(generations_table(evaluation))
    return tables
