"""Build the paper's tables (Table I efficiency, Table II accuracy) from an :class:`Evaluation`."""

from __future__ import annotations

from lightemma.evaluation.core import Evaluation
from lightemma.evaluation.paper import (
    ACCURACY_DIFF_KEYS,
    EFFICIENCY_DIFF_KEYS,
    PAPER_CONVENTION,
    beside_paper,
    paper_accuracy_rows,
    paper_efficiency_rows,
)
from lightemma.tables import ACCURACY_COLUMNS, EFFICIENCY_COLUMNS, Table


def accuracy_table(evaluation: Evaluation, convention: str, *, with_paper: bool = False) -> Table:
    """Table II for one convention; with the paper, each run beside the paper's row of its model (``lightemma`` only)."""
    rows = evaluation.accuracy_rows(convention)
    scope = f"{evaluation.n_common} frames valid for every run" if evaluation.common else "each run's valid frames"
    title = f"Accuracy — {convention} convention ({scope})"
    if with_paper and convention == PAPER_CONVENTION:
        rows = beside_paper(evaluation.models, rows, paper_accuracy_rows(), ACCURACY_DIFF_KEYS)
    return Table(title, ACCURACY_COLUMNS, rows, name=f"accuracy_{convention}")


def efficiency_table(evaluation: Evaluation, *, with_paper: bool = False) -> Table:
    """Table I (time, cost, tokens, GPUs) plus run wall time and frames/s."""
    rows = evaluation.efficiency_rows()
    if with_paper:
        rows = beside_paper(evaluation.models, rows, paper_efficiency_rows(), EFFICIENCY_DIFF_KEYS)
    return Table("Efficiency — per frame, all attempts", EFFICIENCY_COLUMNS, rows, name="efficiency")


def evaluation_tables(evaluation: Evaluation, *, with_paper: bool = False) -> list[Table]:
    """Efficiency first (Table I), then accuracy per evaluated convention (Table II)."""
    return [efficiency_table(evaluation, with_paper=with_paper)] + [
        accuracy_table(evaluation, c, with_paper=with_paper) for c in evaluation.conventions
    ]
