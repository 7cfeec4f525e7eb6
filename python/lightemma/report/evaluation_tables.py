"""Build the paper's tables (Table I efficiency, Table II accuracy) from an :class:`Evaluation`,
plus the paired comparisons (``pairwise_ade``) and the per-family generation verdicts."""

from __future__ import annotations

from typing import Any

from lightemma._text import printable
from lightemma.definitions import COLLISION_FOR_ADE, EGO_LENGTH, EGO_OFFSET, EGO_WIDTH, MIN_STEP
from lightemma.evaluation.ablations import PAIRED_METRICS
from lightemma.evaluation.core import LOW_COVERAGE, Evaluation
from lightemma.evaluation.descriptors import footer_lines, map_line, provenance
from lightemma.evaluation.planning_score import GT_LABEL, KEYS
from lightemma.evaluation.safety import FLOOR_LABEL
from lightemma.frames.fingerprint import describe_fingerprint
from lightemma.models.names import beside_paper
from lightemma.models.paper import (
    ACCURACY_DIFF_KEYS,
    EFFICIENCY_DIFF_KEYS,
    PAPER_CONVENTION,
    paper_accuracy_rows,
    paper_efficiency_rows,
)
from lightemma.report.robustness_tables import robustness_tables
from lightemma.report.tables import (
    ACCURACY_COLUMNS,
    BATCH_TURNAROUND_COLUMN,
    EFFICIENCY_COLUMNS,
    REFERENCE_FRAME_SET,
    SAFETY_COLUMNS,
    Column,
    Table,
    coverage_note,
    fixed,
    markdown_text,
)


def coverage_flags(evaluation: Evaluation) -> dict[str, str]:
    """Model label -> the note every table prints after the name of a model with < 50 % scored frames."""
    return {m.label: coverage_note(m.scored_pct) for m in evaluation.models if m.low_coverage}


def _notes(evaluation: Evaluation, *, intervals: bool = False) -> list[str]:
    notes = []
    if coverage_flags(evaluation):
        notes.append(
            f"Flagged: fewer than {100 * LOW_COVERAGE:.0f} % of the model's frames were scored; its numbers describe only the frames it managed."
        )
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
    flags, notes = coverage_flags(evaluation), _notes(evaluation, intervals=True)
    for row in rows:
        if row.get("ci95_unavailable"):
            # the row is computed; only its interval is missing, and the note says why
            flags[row["model"]] = flags.get(row["model"], "") + " (no interval)"
            notes.append(f"{row['model']}: {row['ci95_unavailable']}.")
    columns, count_notes = _outcome_columns(rows)
    notes = [*count_notes, *notes]
    if any(row.get("samples") for row in rows):  # --samples K runs: minADE@K / minFDE@K beside ADE and FDE
        at = next(i for i, c in enumerate(columns) if c.key == "fde") + 1
        columns = (
            *columns[:at],
            Column("samples", "K"),
            Column("minade", "minADE@K (m)", fixed(2)),
            Column("minfde", "minFDE@K (m)", fixed(2)),
            Column("spread_m", "Spread@K (m)", fixed(2)),
            *columns[at:],
        )
        notes.append(
            "K: samples per frame (--samples); minADE@K / minFDE@K: per frame the best of its K samples, "
            "averaged; Spread@K: mean pairwise distance of the samples' final points (docs/definitions.md#k-samples)."
        )
    if with_paper and convention == PAPER_CONVENTION:
        rows = beside_paper(evaluation.models, rows, paper_accuracy_rows(), ACCURACY_DIFF_KEYS)
        for row in rows:
            if row.get("source") == "paper":  # the paper scored every frame it counts: its 3,908 are its frames
                row.setdefault("frames_accounted", row.get("frames"))
        # the paper has no safety columns: its table stays as it was, safety goes in a table of its own
        return Table(title, columns, rows, name=f"accuracy_{convention}", flags=flags, notes=notes)
    if evaluation.safety is None:
        return Table(title, columns, rows, name=f"accuracy_{convention}", flags=flags, notes=notes)
    return Table(
        title,
        (*columns, *SAFETY_COLUMNS),
        _with_floor(evaluation, rows, convention),
        name=f"accuracy_{convention}",
        flags=flags,
        notes=notes + safety_notes(evaluation, convention),
    )


def _outcome_columns(rows: list[dict]) -> tuple[tuple[Column, ...], list[str]]:
    """Table II's columns: "Frames" (the frames accounted, as in Table I) = Scored + Failed + Implausible + API errors
    (+ "Other unscored", shown only where a run has such frames: no usable ground truth or no finite trajectory)."""
    for row in rows:
        values = [row.get(k) for k in ("scored", "failed", "implausible", "api_errors")]
        counted = [c for c in values if isinstance(c, int)]
        if row.get("frames_accounted") is not None and len(counted) == len(values):
            row["unscored_other"] = row["frames_accounted"] - sum(counted)
    if not any(row.get("unscored_other") for row in rows):
        return ACCURACY_COLUMNS, []
    at = next(i for i, c in enumerate(ACCURACY_COLUMNS) if c.key == "api_errors") + 1
    columns = (*ACCURACY_COLUMNS[:at], Column("unscored_other", "Other unscored"), *ACCURACY_COLUMNS[at:])
    return columns, [
        "Other unscored: frames neither scored nor failed, implausible or lost to API errors (no usable ground truth, or no finite trajectory)."
    ]


def _with_floor(evaluation: Evaluation, rows: list[dict], convention: str) -> list[dict]:
    floor = evaluation.safety.floor.get(convention) if evaluation.safety is not None else None
    return [*rows, {**floor, "source": "floor"}] if floor else rows


def safety_notes(evaluation: Evaluation, convention: str) -> list[str]:
    """What the safety columns mean in a table of ``convention`` (docs/definitions.md#safety)."""
    cc = COLLISION_FOR_ADE[convention]
    how = {
        "uniad": "Col. Ts: share of frames whose footprint overlaps an agent at T (UniAD's obj_box_col); Collision: their mean",
        "stp3": "Col. Ts: per-step collision rate averaged over 0.5 s … T (ST-P3/VAD); Collision: their mean",
        "any": "Col. Ts: share of frames colliding anywhere in 0.5 s … T (BEV-Planner); Collision: the frame outcome over 3 s",
    }[cc]
    masked = (
        "steps where the ground truth collides too are not counted (as in its source)"
        if cc in ("uniad", "stp3")
        else "ground-truth collisions not masked"
    )
    return [
        f"Safety ({cc} collision convention): {how}; {masked}. Off-road: some corner of the {EGO_LENGTH} × {EGO_WIDTH} m ego footprint "
        f"(centre {EGO_OFFSET:.3f} m ahead of the rear axle, heading along the trajectory, kept for steps < {MIN_STEP:g} m) off the drivable area "
        "at some step; Off-road Ts at T; centre: the reference point only (the devkit's test). Vehicles and vulnerable road users (VRU: "
        f"pedestrians, cyclists, motorcyclists) apart. '{FLOOR_LABEL}': the ground truth's own unmasked rates on every evaluated frame. "
        "Drivable area: map expansion polygons (expansion) or the base map mask (mask: drivable surface and sidewalks). "
        "Off-road and Collision intervals: exact binomial on the scene-clustered effective sample size (never [0, 0] at 0 %)."
    ]


def safety_table(evaluation: Evaluation, convention: str) -> Table:
    """The safety columns of one convention in a table of their own (beside ``--with-paper``'s accuracy table)."""
    cols = (Column("model", "Model"), Column("frames", "Frames"), *SAFETY_COLUMNS)
    rows = _with_floor(evaluation, evaluation.accuracy_rows(convention), convention)
    return Table(
        f"Safety — {convention} convention",
        cols,
        rows,
        name=f"safety_{convention}",
        flags=coverage_flags(evaluation),
        notes=safety_notes(evaluation, convention),
    )


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
    notes = [
        f"A − B in percentage points (< 0: A is safer), paired on the frames where both have a value; {100 * r.confidence:g} % "
        f"scene-bootstrap interval; p from {r.n_resamples} sign flips of scene-level differences; Holm family: the {len(evaluation.pairwise_safety or [])} rows of this table "
        f"(every pair, off-road and collision together). Collision: {cc} convention.",
        HOLM_FAMILIES,
    ]
    return Table(
        f"Paired comparisons — off-road and collision, {evaluation.main_convention} table",
        PAIRWISE_SAFETY_COLUMNS,
        list(evaluation.pairwise_safety or []),
        name="pairwise_safety",
        flags=coverage_flags(evaluation),
        notes=notes,
    )


def efficiency_table(evaluation: Evaluation, *, with_paper: bool = False) -> Table:
    """Table I (time, cost, tokens, GPUs) plus run wall time and frames/s."""
    rows = evaluation.efficiency_rows()
    if with_paper:
        rows = beside_paper(evaluation.models, rows, paper_efficiency_rows(), EFFICIENCY_DIFF_KEYS)
    columns, notes = EFFICIENCY_COLUMNS, _notes(evaluation)
    if any(
        "batch_turnaround_s" in row for row in rows
    ):  # a batch run: its latency is n/a, its batches' turnaround shown
        at = next(i for i, c in enumerate(columns) if c.key == "seconds_per_frame") + 1
        columns = (*columns[:at], BATCH_TURNAROUND_COLUMN, *columns[at:])
        notes = [
            *notes,
            "Batch runs (lightemma run --batch): per-frame time is n/a (a frame waits for its batches); "
            "Batch turnaround is the mean time from a batch's submission to its results; cost at batch prices "
            "(or at the run's --price).",
        ]
    return Table(
        "Efficiency — per frame, all attempts",
        columns,
        rows,
        name="efficiency",
        flags=coverage_flags(evaluation),
        notes=notes,
    )


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


#: said under every table with a "p (Holm)" column: its family is its own rows, so one comparison can differ between tables
HOLM_FAMILIES = (
    "Each table corrects over its own family (its rows, as said above): the same comparison can be significant in "
    "one table and not in another, whose family is larger or smaller."
)


def pairwise_table(evaluation: Evaluation) -> Table:
    """Every pair of runs: mean paired ADE-avg difference on common frames, interval, p-values (``pairwise_ade``)."""
    r = evaluation.resampling
    notes = [
        f"A − B < 0: A is better. Paired on the frames scored in both runs; {100 * r.confidence:g} % scene-bootstrap interval; "
        f"p from {r.n_resamples} sign flips of scene-level differences; Holm family: all {len(evaluation.pairwise or [])} pairs of this table; "
        f"significant: p (Holm) ≤ {1 - r.confidence:.2f}.",
        HOLM_FAMILIES,
        *_notes(evaluation)[:1],
    ]
    title = f"Paired comparisons — ADE avg, {evaluation.main_convention} convention"
    return Table(
        title,
        PAIRWISE_COLUMNS,
        list(evaluation.pairwise or []),
        name="pairwise_ade",
        flags=coverage_flags(evaluation),
        notes=notes,
    )


def generations_table(evaluation: Evaluation) -> Table:
    """Per family, each generation against its predecessor: better, worse or not distinguishable."""
    notes = [
        "Change = newer − older (negative: the newer generation is better); a verdict needs p (Holm) ≤ "
        f"{1 - evaluation.resampling.confidence:.2f}, else not distinguishable. p (Holm) is the paired-comparisons table's (Holm family: "
        f"all {len(evaluation.pairwise or [])} pairs of runs).",
        *_notes(evaluation)[:1],
    ]
    return Table(
        "Generations — is each generation better than its predecessor?",
        GENERATION_COLUMNS,
        evaluation.generations(),
        name="generations",
        flags=coverage_flags(evaluation),
        notes=notes,
    )


def _significant(value: object) -> str:
    return "-" if value is None else ("yes" if value else "no")


def _paired_metric_columns(diff: str, sides: tuple[tuple[str, str], tuple[str, str]], diff_header: str) -> list[Column]:
    """Per metric of :data:`~lightemma.evaluation.ablations.PAIRED_METRICS`: both sides, the difference [CI], p (Holm), verdict."""
    out: list[Column] = []
    for m in PAIRED_METRICS:
        unit = f" ({m.unit})" if m.unit else ""
        out += [Column(f"{m.key}_{side}", f"{m.title} {name}{unit}", fixed(3)) for side, name in sides]
        out += [
            Column(f"{m.key}_{diff}", f"{m.title} {diff_header}{unit} [95% CI]", fixed(3), ci=f"{m.key}_ci95"),
            Column(f"{m.key}_p_holm", f"{m.title} p (Holm)", fixed(4)),
            Column(f"{m.key}_significant", f"{m.title} significant", _significant),
        ]
    return out


def _paired_note(evaluation: Evaluation, rows: int) -> str:
    r = evaluation.resampling
    return (
        f"Paired on the frames scored in both runs; {100 * r.confidence:g} % scene-bootstrap interval; p from {r.n_resamples} "
        f"sign flips of scene-level differences; Holm family: the {rows} row(s) of this table, per metric; significant: "
        f"p (Holm) ≤ {1 - r.confidence:.2f}. " + HOLM_FAMILIES
    )


def input_ablation_table(evaluation: Evaluation) -> Table:
    """Does the image matter? Each ablation run against its model's full run: full − ablated, CI, Holm p (``input_ablations``)."""
    columns = [
        Column("model", "Model (full inputs)"),
        Column("ablation", "Ablation"),
        Column("frames", "Common frames"),
        Column("scenes", "Scenes"),
        *_paired_metric_columns("diff", (("full", "full"), ("ablated", "ablated")), "full − ablated"),
    ]
    notes = [
        "full − ablated < 0: the model is better with what the ablation takes away (the image, or the history) — it uses it; "
        "≈ 0: it does not. no-image: no image in any stage; blank-image: a uniform grey image of the frame's size; "
        "no-history: the prompts without the history numbers; corrupt:NAME@S: the image corrupted at severity S; "
        "history-noise@SV[,SK] / history-stale@K: a perturbed history (docs/definitions.md#input-ablations).",
        _paired_note(evaluation, len(evaluation.input_ablations)),
        *_notes(evaluation)[:1],
    ]
    return Table(
        f"Does the image matter? — input ablations, {evaluation.main_convention} convention",
        columns,
        list(evaluation.input_ablations),
        name="input_ablations",
        flags=coverage_flags(evaluation),
        notes=notes,
    )


def baseline_gain_table(evaluation: Evaluation) -> Table:
    """Each model's gain over the best baseline (constant, cv, ego) on their common frames (``baseline_gains``)."""
    columns = [
        Column("model", "Model"),
        Column("inputs", "Inputs"),
        Column("baseline", "Best baseline"),
        Column("frames", "Common frames"),
        Column("scenes", "Scenes"),
        *_paired_metric_columns("gain", (("model", "model"), ("baseline", "baseline")), "gain (baseline − model)"),
    ]
    notes = [
        "Gain > 0: the model beats the best of the constant, constant-velocity and ego-status baselines by that much "
        "(best: the lowest ADE avg on the frames scored in both); ≤ 0: the history alone does as well. An ego baseline "
        "cross-fitted on a --sample / --limit subset fits on few frames and inflates every gain (its run warns; "
        "manifest backend.fit.subset): use --fit-split train or the full set.",
        _paired_note(evaluation, len(evaluation.baseline_gains)),
        *_notes(evaluation)[:1],
    ]
    return Table(
        f"Gain over the best baseline — {evaluation.main_convention} convention",
        columns,
        list(evaluation.baseline_gains),
        name="baseline_gains",
        flags=coverage_flags(evaluation),
        notes=notes,
    )


def ablation_tables(evaluation: Evaluation) -> list[Table]:
    """The "does the image matter?" tables that have rows: input ablations, gains over the best baseline."""
    tables = []
    if evaluation.input_ablations:
        tables.append(input_ablation_table(evaluation))
    if evaluation.baseline_gains:
        tables.append(baseline_gain_table(evaluation))
    return tables


def evaluation_tables(evaluation: Evaluation, *, with_paper: bool = False) -> list[Table]:
    """Efficiency first (Table I), then accuracy per evaluated convention (Table II), then the paired comparisons if computed,
    then the input ablations and gains over the best baseline where the runs hold them."""
    tables = [efficiency_table(evaluation, with_paper=with_paper)] + [
        accuracy_table(evaluation, c, with_paper=with_paper) for c in evaluation.conventions
    ]
    if with_paper and evaluation.safety is not None and PAPER_CONVENTION in evaluation.conventions:
        tables.append(safety_table(evaluation, PAPER_CONVENTION))
    if evaluation.pairwise:  # computed, and at least two runs
        tables.append(pairwise_table(evaluation))
        if evaluation.generations():
            tables.append(generations_table(evaluation))
    if any(r["diff"] is not None for r in evaluation.pairwise_safety or []):  # some pair has common frames with values
        tables.append(pairwise_safety_table(evaluation))
    if (
        evaluation.planning is not None and evaluation.planning.shown
    ):  # the planning score (NAVSIM), after the safety columns
        tables.append(planning_table(evaluation))
        if any(r["diff"] is not None for r in evaluation.planning.pairwise or []):
            tables.append(pairwise_planning_table(evaluation))
    if evaluation.explanations is not None and evaluation.explanations.shown:  # some run has stage-2 texts
        tables.append(explanations_table(evaluation))
        if evaluation.explanations.ablations:
            tables.append(intent_ablation_table(evaluation))
        if evaluation.explanations.objects_shown:  # some run has descriptions and annotation states
            tables.append(described_objects_table(evaluation))

    return tables + ablation_tables(evaluation) + robustness_tables(evaluation)


def provenance_footer(lines: list[str], fmt: str) -> str:
    """The compact provenance footer under Markdown, LaTeX or CSV tables (``lines``:
    :func:`lightemma.evaluation.descriptors.footer_lines`): a ``####`` block, ``%`` or ``#`` comment lines."""
    if fmt == "md":
        return "\n#### Provenance\n\n" + "".join(f"- {markdown_text(line)}\n" for line in lines)
    mark = {"latex": "%", "csv": "#"}[fmt]
    return "\n" + "".join(f"{mark} {printable(line)}\n" for line in ["provenance:", *lines])


def provenance_table(evaluation: Evaluation) -> Table:
    """The report's "Provenance" panel: software, each frame set's fingerprint with its runs, each run's prompt set, parse
    mode and the source of its safety columns, and the ids of the metrics shown (lightemma.evaluation.descriptors)."""
    prov = provenance(evaluation)
    lines = footer_lines(evaluation)
    rows: list[dict[str, str]] = [{"item": "Software", "value": lines[0]}]
    for fp in prov["frame_sets"].values():
        users = ", ".join(r["model"] for r in prov["runs"] if r["frame_set"] == fp["id"])
        rows.append({"item": f"Frame set {describe_fingerprint(fp)}", "value": users})
    maps = map_line(evaluation)
    if maps:
        rows.append({"item": "Maps", "value": maps.removeprefix("Maps: ")})
    rows.append({"item": "Metrics", "value": lines[-1].removeprefix("Metrics: ")})
    for run in prov["runs"]:
        prompt = run["prompt_set"]
        source = run["safety_source"] or run.get("planning_source") or {}
        area = source.get("drivable_area") or source.get("map")
        version = source.get("map_expansion_version")
        value = (
            f"frames {run['frame_set']}; prompts {prompt.get('name')} {prompt.get('hash') or ''}; parse {run['parse']}; "
            f"{run['integrator']}; drivable area {area or 'n/a'}"
            + (f" (map expansion {version})" if version else "")
            + "; lightemma "
            f"{run['lightemma_version'] or '?'}" + (" (imported)" if run["imported"] else "")
        )
        rows.append({"item": run["model"], "value": value})
    return Table(
        "Provenance",
        (Column("item", "What"), Column("value", "Which")),
        rows,
        name="provenance",
        notes=[
            "What each number is: docs/evaluate.md#what-each-number-is; every column's descriptor: "
            "lightemma evaluate --format json."
        ],
    )


#: the explanation audit's columns (docs/definitions.md#explanation-audit): rates in [0, 1], n/a with the reason
EXPLANATION_COLUMNS: tuple[Column, ...] = (
    Column("model", "Model"),
    Column("explanation_frames", "Frames"),
    Column("consistent", "Consistent [95% CI]", fixed(3), ci="consistent_ci95", na="consistent_na"),
    Column("contradicts", "Contradicts [95% CI]", fixed(3), ci="contradicts_ci95", na="contradicts_na"),
    Column("intent_unknown", "Unknown [95% CI]", fixed(3), ci="intent_unknown_ci95", na="intent_unknown_na"),
    Column("intent_accuracy", "Intent accuracy [95% CI]", fixed(3), ci="intent_accuracy_ci95", na="intent_accuracy_na"),
    # the described objects (docs/definitions.md#described-objects)
    Column(
        "hallucinated_pedestrian",
        "Hallucinated pedestrian [95% CI]",
        fixed(3),
        ci="hallucinated_pedestrian_ci95",
        na="hallucinated_pedestrian_na",
    ),
    Column(
        "missed_pedestrian",
        "Missed pedestrian [95% CI]",
        fixed(3),
        ci="missed_pedestrian_ci95",
        na="missed_pedestrian_na",
    ),
)


def explanations_table(evaluation: Evaluation) -> Table:
    """ "Explanations": per model the shares of frames whose stated intent (stage 2) is consistent with, contradicts or
    cannot be checked against its plan (stage 3), and its intent accuracy against the ground truth's behaviour
    (``Evaluation.explanations``, lightemma.evaluation.intent_audit)."""
    rows = [{"model": m.label, **m.explanations} for m in evaluation.models]
    r = evaluation.resampling
    notes = [
        "The stated intent of stage 2, read without a judge (rules intent@lightemma/1), against the plan of stage 3 "
        "(Consistent / Contradicts / Unknown: shares of the frames) and against what the car did, the same classes "
        "from the ground truth (Intent accuracy: share of the frames whose stated intent is consistent with it). "
        "Rates in [0, 1]; runs without stage-2 texts (baselines) are n/a (docs/definitions.md#explanation-audit).",
        "Hallucinated pedestrian: share of the frames whose stage-1 description affirms a pedestrian while no pedestrian "
        "box projects into the image; Missed pedestrian: share whose description does not affirm one while one is in "
        "view (docs/definitions.md#described-objects).",
    ]
    if r.n_resamples:
        notes.append(
            f"[low, high]: {100 * r.confidence:g} % scene-level bootstrap interval ({r.n_resamples} resamples, seed {r.seed})."
        )
    return Table(
        "Explanations", EXPLANATION_COLUMNS, rows, name="explanations", flags=coverage_flags(evaluation), notes=notes
    )


def described_objects_table(evaluation: Evaluation) -> Table:
    """ "Described objects": per model and class, how often the stage-1 description affirms the class, how often it is
    in view, and the mention precision and recall against the annotations (``ExplanationResult.object_classes``,
    lightemma.evaluation.object_audit)."""
    cols = (
        Column("model", "Model"),
        Column("class", "Class"),
        Column("frames", "Frames"),
        Column("mentions", "Mentions"),
        Column("in_view", "In view"),
        Column(
            "mention_precision", "Precision [95% CI]", fixed(3), ci="mention_precision_ci95", na="mention_precision_na"
        ),
        Column("mention_recall", "Recall [95% CI]", fixed(3), ci="mention_recall_ci95", na="mention_recall_na"),
    )
    return Table(
        "Described objects",
        cols,
        list(evaluation.explanations.object_classes),
        name="described_objects",
        notes=[
            "The object classes the stage-1 description affirms (rules objects@lightemma/1; negated and hedged "
            "mentions are not claims) against the annotated boxes in view of CAM_FRONT (some corner in the "
            "image, visibility >= 40 %, within the class's nuScenes detection range). Precision: share of the "
            "affirmed mentions whose class is in view, over frames where it is in view or absent from the "
            "image; recall: share of the frames with the class in view whose description affirms it. Traffic "
            "lights and signs are map objects without annotations: n/a (docs/definitions.md#described-objects)."
        ],
    )


def intent_ablation_table(evaluation: Evaluation) -> Table:
    """ "Stated intent without the image": per ablation run, the share of frames whose stated intent differs from the
    full run's (``ExplanationResult.ablations``)."""
    cols = (
        Column("model", "Model"),
        Column("ablation", "Ablation"),
        Column("ablated", "Ablated run"),
        Column("frames", "Frames"),
        Column("intent_changed", "Intent changed [95% CI]", fixed(3), ci="intent_changed_ci95", na="intent_changed_na"),
    )
    return Table(
        "Stated intent without the image",
        cols,
        list(evaluation.explanations.ablations),
        name="intent_ablations",
        notes=[
            "Share of the frames both runs answered with a stage-2 text whose stated intent (longitudinal and "
            "lateral class, unknown included) differs between the full run and its ablation "
            "(docs/definitions.md#explanation-audit)."
        ],
    )


#: the planning score's columns (docs/definitions.md#planning-score): means in [0, 1], n/a with the reason
_PLANNING_TITLES = {
    "pdms": "PDMS",
    "epdms": "EPDMS",
    "epdms_map": "EPDMS-map",
    "nc": "NC",
    "dac": "DAC",
    "ddc": "DDC",
    "tlc": "TLC",
    "ep": "EP",
    "ttc": "TTC",
    "lk": "LK",
    "c": "C",
    "hc": "HC",
    "ec": "EC",
}


def planning_columns(headline: str) -> tuple[Column, ...]:
    """Model, frames, the headline aggregate and PDMS with their intervals, then the other aggregate and every sub-score."""
    lead = [headline] + [k for k in ("pdms",) if k != headline]
    rest = [k for k in KEYS if k not in lead]
    cols = [Column("model", "Model"), Column("planning_frames", "Frames")]
    cols += [Column(k, f"{_PLANNING_TITLES[k]} [95% CI]", fixed(3), ci=f"{k}_ci95", na=f"{k}_na") for k in lead]
    cols += [Column(k, _PLANNING_TITLES[k], fixed(3), na=f"{k}_na") for k in rest]
    return (*cols, Column("planning_map", "Drivable area"))


def planning_table(evaluation: Evaluation) -> Table:
    """ "Planning score (NAVSIM)": per model its PDMS / EPDMS (or EPDMS-map) and sub-scores, and the ground truth's own row
    scored by the same code (``Evaluation.planning``, lightemma.evaluation.planning_score)."""
    result = evaluation.planning
    rows = [{"model": m.label, **m.planning} for m in evaluation.models]
    if result.ground_truth:
        rows.append({**result.ground_truth, "source": "ground truth"})
    r = evaluation.resampling
    notes = [
        "NAVSIM's planning score on each model's scored frames, re-simulated (LQR tracker on a kinematic bicycle, 0.1 s, 3 s) "
        "from the initial state derived from the ego poses: PDMS = NC·DAC·(5EP + 5TTC + 2C)/12; EPDMS = NC·DAC·DDC·TLC·"
        "(5EP + 5TTC + 2LK + 2HC + 2EC)/16 with the human-penalty filter (with annotations); EPDMS-map = DAC·DDC·(5EP + 2LK + "
        "2HC + 2EC)/11 (without annotations). TLC is n/a (nuScenes has no traffic-light states) and counted as 1. Means in "
        "[0, 1] over the frames that have a value; n/a (why) where none has (docs/definitions.md#planning-score).",
        f"'{GT_LABEL}': the ground truth scored by the same code on every evaluated frame (NAVSIM's human agent scores about "
        "0.94 PDMS on navtest; here the ground truth also stands in for PDM-Closed in EP, so its EP is 1 wherever it moves "
        "more than 5 m).",
    ]
    if r.n_resamples:
        notes.append(
            f"[low, high]: {100 * r.confidence:g} % scene-level bootstrap interval ({r.n_resamples} resamples, seed {r.seed})."
        )
    return Table(
        "Planning score (NAVSIM)",
        planning_columns(result.headline),
        rows,
        name="planning",
        flags=coverage_flags(evaluation),
        notes=notes,
    )


def pairwise_planning_table(evaluation: Evaluation) -> Table:
    """Every pair of runs on the headline planning aggregate (``PlanningResult.pairwise``)."""
    result = evaluation.planning
    r = evaluation.resampling
    title = _PLANNING_TITLES.get(result.headline, result.headline)
    cols = (
        Column("model_a", "Model A"),
        Column("model_b", "Model B"),
        Column("frames", "Common frames"),
        Column("scenes", "Scenes"),
        Column("diff", f"{title} A − B [95% CI]", fixed(3), ci="ci95"),
        Column("p_value", "p", fixed(4)),
        Column("p_holm", "p (Holm)", fixed(4)),
        Column("significant", "Significant", _significant),
    )
    notes = [
        f"A − B > 0: A scores higher. Paired on the frames where both have a value; {100 * r.confidence:g} % scene-bootstrap "
        f"interval; p from {r.n_resamples} sign flips of scene-level differences; Holm family: the {len(result.pairwise or [])} rows of "
        "this table.",
        HOLM_FAMILIES,
    ]
    return Table(
        f"Paired comparisons — planning score ({title})",
        cols,
        list(result.pairwise or []),
        name="pairwise_planning",
        flags=coverage_flags(evaluation),
        notes=notes,
    )


# ------------------------------------------------------------------------------------- tables that refuse to mix


_REFERENCE_LABEL = (
    "Reference rows, not runs: the ground truth's on every evaluated frame of all frame sets, the paper's on its own"
)


def _is_run_row(row: dict[str, Any], labels: set[str] | dict[str, Any]) -> bool:
    """A run's own row: its ``model`` is a run's label and it is no paper, difference, floor or ground-truth row."""
    return row.get("model") in labels and row.get("source") is None


def _run_rows(table: Table, evaluation: Evaluation) -> bool:
    """True when some row of ``table`` is a run's (:func:`_is_run_row`)."""
    labels = {m.label for m in evaluation.models}
    return any(_is_run_row(r, labels) for r in table.rows)


def _row_frame_sets(rows: list[dict[str, Any]], group_of: dict[str, str]) -> list[str | None]:
    """Per row its frame set's key (``group_of``: run label -> key), None for a reference row. A run's row is its run's;
    the paper's row right after it and the difference row right after that (``--with-paper``: lightemma.models.paper
    .beside_paper) stay beside it, in its group; every other row (the paper's other models, the floor, the ground
    truth's) is a reference row."""
    out: list[str | None] = []
    current, state = None, None
    for i, r in enumerate(rows):
        source = r.get("source")
        paired = i + 1 < len(rows) and rows[i + 1].get("source") == "diff"  # beside_paper emits a match with its Δ
        if _is_run_row(r, group_of):
            current, state = group_of[r["model"]], "run"
            out.append(current)
        elif source == "paper" and state == "run" and paired:
            state = "paper"
            out.append(current)
        elif source == "diff" and state == "paper":
            state = None
            out.append(current)
        else:
            current, state = None, None
            out.append(None)
    return out


def frame_set_tables(tables: list[Table], evaluation: Evaluation) -> list[Table]:
    """Tables in which runs on different frame sets are never ranked in one column
    (docs/evaluate.md#runs-on-different-frame-sets): the one rule of ``lightemma evaluate`` (Markdown, CSV, LaTeX) and
    ``lightemma report`` (index.md, tables/, index.html).

    With one frame set, or with ``--common`` (every run scored on the same frames), ``tables`` unchanged. Otherwise each
    table whose rows are runs becomes one table per frame set, in the order of the evaluation's runs: its fingerprint
    (id, version, split, window, frame count: :func:`~lightemma.frames.fingerprint.describe_fingerprint`) in the title
    and in ``Table.frame_set`` / ``Table.frame_set_label``, and one more for its reference rows (the ground truth's,
    computed on every evaluated frame, or the paper's; ``frame_set`` :data:`REFERENCE_FRAME_SET`); tables of pairs stay
    whole (each pair is scored on the frames scored in both). Where the runs' prompt sets differ, a note under each run
    table says which run used which prompt set."""
    from dataclasses import replace

    groups: dict[str, list[str]] = {}
    described: dict[str, str] = {}
    group_of: dict[str, str] = {}
    for m in evaluation.models:
        fp = m.fingerprint
        key = fp["id"] if fp is not None else "unrecorded"
        described[key] = describe_fingerprint(fp) if fp is not None else "unrecorded (no fingerprint)"
        groups.setdefault(key, []).append(m.label)
        group_of[m.label] = key
    notes = _mixed_settings_notes(evaluation)
    if evaluation.common or len(groups) <= 1:
        if not notes:
            return list(tables)
        return [replace(t, notes=[*t.notes, *notes]) if _run_rows(t, evaluation) else t for t in tables]
    out = []
    for table in tables:
        if not _run_rows(table, evaluation):
            out.append(table)
            continue
        where = _row_frame_sets(table.rows, group_of)
        for key in groups:
            rows = [r for r, k in zip(table.rows, where, strict=True) if k == key]
            if rows:
                title = f"{table.title} — frame set {described[key]}"
                out.append(
                    replace(
                        table,
                        title=title,
                        rows=rows,
                        notes=[*table.notes, *notes],
                        frame_set=key,
                        frame_set_label=described[key],
                    )
                )
        rest = [r for r, k in zip(table.rows, where, strict=True) if k is None]
        if rest:
            title = f"{table.title} — reference rows (on every evaluated frame, all frame sets)"
            out.append(
                replace(table, title=title, rows=rest, frame_set=REFERENCE_FRAME_SET, frame_set_label=_REFERENCE_LABEL)
            )
    return out


def frame_set_groups(evaluation: Evaluation) -> list[dict[str, Any]] | None:
    """``[{"frame_set": id, "models": [label, …]}, …]`` where runs' frame sets differ and ``--common`` was not given,
    else None (``evaluate --format json``'s and the report's ``frame_set_groups``;
    docs/evaluate.md#runs-on-different-frame-sets)."""
    groups: dict[str | None, list[str]] = {}
    for m in evaluation.models:
        groups.setdefault(m.fingerprint["id"] if m.fingerprint is not None else None, []).append(m.label)
    if evaluation.common or len(groups) <= 1:
        return None
    return [{"frame_set": key, "models": labels} for key, labels in groups.items()]


def json_frame_set_rows(tables: list[Table], evaluation: Evaluation) -> list[Table]:
    """``tables`` whose run rows carry ``frame_set``, their run's fingerprint id (for runs on different frame sets)."""
    from dataclasses import replace

    fps = {m.label: m.fingerprint["id"] if m.fingerprint is not None else None for m in evaluation.models}
    return [
        replace(t, rows=[{**r, "frame_set": fps[r["model"]]} if _is_run_row(r, fps) else r for r in t.rows])
        if _run_rows(t, evaluation)
        else t
        for t in tables
    ]


def _mixed_settings_notes(evaluation: Evaluation) -> list[str]:
    """A note naming which run used which prompt set where they differ; [] if none. (The parse definition is the
    accuracy tables' Parse column, the integrator and the other protocol settings are in each run's label.)"""
    prompts: dict[str, list[str]] = {}
    for m in evaluation.models:
        manifest = m.manifest or {}
        prompt_value = manifest.get("prompt_set")
        prompt: dict[str, Any] = prompt_value if isinstance(prompt_value, dict) else {}
        name = f"{prompt.get('name')} ({str(prompt.get('hash'))[:19]})" if prompt else "unrecorded"
        if prompt.get("variant"):
            name += f", variant {prompt.get('variant')}"
        prompts.setdefault(name, []).append(m.label)
    notes = []
    for what, seen in (("prompt sets", prompts),):  # parse definitions: the accuracy tables' Parse column
        if len(seen) > 1:
            which = "; ".join(f"{k}: {', '.join(v)}" for k, v in seen.items())
            notes.append(f"Runs differ in {what}: {which} (not one protocol).")
    return notes
