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
from lightemma.tables import ACCURACY_COLUMNS, EFFICIENCY_COLUMNS, SAFETY_COLUMNS, Column, Table, coverage_note, fixed


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
        # the paper has no safety columns: its table stays as it was, safety goes in a table of its own
        return Table(title, ACCURACY_COLUMNS, rows, name=f"accuracy_{convention}", flags=coverage_flags(evaluation), notes=_notes(evaluation, intervals=True))
    if evaluation.safety is None:
        return Table(title, ACCURACY_COLUMNS, rows, name=f"accuracy_{convention}", flags=coverage_flags(evaluation), notes=_notes(evaluation, intervals=True))
    return Table(title, (*ACCURACY_COLUMNS, *SAFETY_COLUMNS), _with_floor(evaluation, rows, convention), name=f"accuracy_{convention}",
                 flags=coverage_flags(evaluation), notes=_notes(evaluation, intervals=True) + safety_notes(evaluation, convention))


def _with_floor(evaluation: Evaluation, rows: list[dict], convention: str) -> list[dict]:
    floor = evaluation.safety.floor.get(convention) if evaluation.safety is not None else None
    return [*rows, {**floor, "source": "floor"}] if floor else rows


def safety_notes(evaluation: Evaluation, convention: str) -> list[str]:
    """What the safety columns mean in a table of ``convention`` (docs/definitions.md#safety)."""
    from lightemma.evaluation.safety import COLLISION_FOR_ADE, EGO_LENGTH, EGO_OFFSET, EGO_WIDTH, FLOOR_LABEL, MIN_STEP

    cc = COLLISION_FOR_ADE[convention]
    how = {
        "uniad": "Col. Ts: share of frames whose footprint overlaps an agent at T (UniAD's obj_box_col); Collision: their mean",
        "stp3": "Col. Ts: per-step collision rate averaged over 0.5 s … T (ST-P3/VAD); Collision: their mean",
        "any": "Col. Ts: share of frames colliding anywhere in 0.5 s … T (BEV-Planner); Collision: the frame outcome over 3 s",
    }[cc]
    masked = "steps where the ground truth collides too are not counted (as in its source)" if cc in ("uniad", "stp3") else "ground-truth collisions not masked"
    return [
        f"Safety ({cc} collision convention): {how}; {masked}. Off-road: some corner of the {EGO_LENGTH} × {EGO_WIDTH} m ego footprint "
        f"(centre {EGO_OFFSET:.3f} m ahead of the rear axle, heading along the trajectory, kept for steps < {MIN_STEP:g} m) off the drivable area "
        "at some step; Off-road Ts at T; centre: the reference point only (the devkit's test). Vehicles and vulnerable road users (VRU: "
        f"pedestrians, cyclists, motorcyclists) apart. '{FLOOR_LABEL}': the ground truth's own unmasked rates on every evaluated frame. "
        "Drivable area: map expansion polygons (expansion) or the base map mask (mask: drivable surface and sidewalks)."
    ]


def safety_table(evaluation: Evaluation, convention: str) -> Table:
    """The safety columns of one convention in a table of their own (beside ``--with-paper``'s accuracy table)."""
    cols = (Column("model", "Model"), Column("frames", "Frames"), *SAFETY_COLUMNS)
    rows = _with_floor(evaluation, evaluation.accuracy_rows(convention), convention)
    return Table(f"Safety — {convention} convention", cols, rows, name=f"safety_{convention}", flags=coverage_flags(evaluation),
                 notes=safety_notes(evaluation, convention))


PAIRWISE_SAFETY_COLUMNS: tuple[Column, ...] = (
    Column("model_a", "Model A"),
    Column("model_b", "Model B"),
    Column("metric", "Metric"),
    Column("frames", "Common frames"),
    Column("scenes", "Scenes"),
    Column("diff", "A − B (pp) [95% CI]", lambda v: "-" if v is None else f"{100.0 * v:.2f}", ci="ci95"),
    Column("p_value", "p", fixed(4)),
    Column("p_holm", "p (Holm)", fixed(4)),
    Column("significant", "Significant", lambda v: "-" if v is None else ("yes" if v else "no")),
)


def pairwise_safety_table(evaluation: Evaluation) -> Table:
    """Every pair of runs on off-road and collision (``pairwise_safety``)."""
    r = evaluation.resampling
    cc = (evaluation.pairwise_safety or [{}])[0].get("convention", "")
    notes = [f"A − B in percentage points (< 0: A is safer), paired on the frames where both have a value; {100 * r.confidence:g} % "
             f"scene-bootstrap interval; p from {r.n_resamples} sign flips of scene-level differences; Holm over all rows. Collision: {cc} convention."]
    return Table(f"Paired comparisons — off-road and collision, {evaluation.main_convention} table", PAIRWISE_SAFETY_COLUMNS,
                 list(evaluation.pairwise_safety or []), name="pairwise_safety", flags=coverage_flags(evaluation), notes=notes)


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
    if with_paper and evaluation.safety is not None and PAPER_CONVENTION in evaluation.conventions:
        tables.append(safety_table(evaluation, PAPER_CONVENTION))
    if evaluation.pairwise:  # computed, and at least two runs
        tables.append(pairwise_table(evaluation))
        if evaluation.generations():
            tables.append(generations_table(evaluation))
    if any(r["diff"] is not None for r in evaluation.pairwise_safety or []):  # some pair has common frames with values
        tables.append(pairwise_safety_table(evaluation))
    return tables
