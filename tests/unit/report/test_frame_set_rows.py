"""Which frame set each row of a run table belongs to when the runs' frame sets differ (``--with-paper`` rows)."""

from __future__ import annotations

from lightemma.report.evaluation_tables import _row_frame_sets


def test_a_paper_row_stays_with_a_run_only_beside_its_difference_row():
    group_of = {"gpt-4o": "A", "my-finetune": "B"}
    rows = [
        {"model": "gpt-4o"},
        {"model": "GPT-4o", "source": "paper"},
        {"model": "Δ vs paper", "source": "diff"},
        {"model": "my-finetune"},  # no paper row matches it
        {"model": "GPT-5.0", "source": "paper"},  # the paper's other models: reference rows
        {"model": "Claude-3.7-Sonnet", "source": "paper"},
        {"model": "ground truth", "source": "floor"},
    ]
    assert _row_frame_sets(rows, group_of) == ["A", "A", "A", "B", None, None, None]


def test_a_run_row_after_reference_rows_starts_its_own_group():
    group_of = {"a": "A", "b": "B"}
    rows = [
        {"model": "GPT-5.0", "source": "paper"},
        {"model": "b"},
        {"model": "B-paper", "source": "paper"},
        {"model": "Δ vs paper", "source": "diff"},
        {"model": "a"},
    ]
    assert _row_frame_sets(rows, group_of) == [None, "B", "B", "B", "A"]
