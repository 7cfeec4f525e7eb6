"""One labelling rule (issue 32.8): a run's label comes from the run alone — model, every setting that departs from the
paper's protocol (window, integrator, chain, answer format, inputs) and its name — so it never depends on the other runs
in the folder, and neither do its bootstrap intervals (keyed by the label)."""

from __future__ import annotations

import pytest

from lightemma.evaluation import evaluate_runs
from lightemma.evaluation.loading import load_run
from lightemma.evaluation.synthetic import write_synthetic_run


def _run(root, model="openai/gpt-4o", seed=1, **manifest):
    return write_synthetic_run(root, model, 26, seed=seed, noise=0.5, manifest=manifest)


def test_a_named_full_run_beside_an_unnamed_ablation(tmp_path):
    """The issue's case: the ablation was shown as plain "GPT-4o" in Tables I and II."""
    full = _run(tmp_path / "runs", name="full run")
    blind = _run(tmp_path / "runs", seed=2, config={"inputs": "no-image"})
    labels = {m.run_dir: m.label for m in evaluate_runs([tmp_path / "runs"]).models}
    assert labels == {full: 'GPT-4o "full run"', blind: "GPT-4o [no-image]"}


def test_every_setting_and_the_name_are_in_the_label_in_one_order(tmp_path):
    from lightemma.evaluation.core import run_label

    runs = tmp_path / "runs"
    cases = {
        _run(runs): "GPT-4o",
        _run(runs, dataset={"window": "full"}): "GPT-4o [full window]",
        _run(
            runs, config={"dataset": {"window": "full"}, "inputs": "blank-image"}
        ): "GPT-4o [full window, blank-image]",
        _run(runs, integrator="midpoint"): "GPT-4o [midpoint]",
        _run(
            runs, config={"chain": "conversation", "answer_format": "structured"}, name="b"
        ): 'GPT-4o [conversation, structured] "b"',
        _run(runs, name="no-image"): 'GPT-4o "no-image"',  # a name never reads as a setting
        _run(runs, config={"inputs": "no-image"}): "GPT-4o [no-image]",
        _run(runs, "baseline:oracle", integrator="euler"): "baseline:oracle",
    }
    for run_dir, label in cases.items():
        assert run_label(load_run(run_dir).info) == label
    assert sorted(m.label for m in evaluate_runs([runs]).models) == sorted(cases.values())


def test_a_label_and_its_intervals_do_not_depend_on_the_other_runs(tmp_path):
    runs = tmp_path / "runs"
    blind = _run(runs, seed=2, config={"inputs": "no-image"})
    alone = evaluate_runs([blind]).models[0]
    companies = [
        [_run(tmp_path / "a", seed=1)],  # an unnamed full run
        [_run(tmp_path / "b", seed=1, name="named")],  # a named full run
        [_run(tmp_path / "c", seed=3, config={"inputs": "blank-image"}), _run(tmp_path / "c", "baseline:cv", seed=4)],
    ]
    for others in companies:
        model = next(m for m in evaluate_runs([blind, *others]).models if m.run_dir == blind)
        assert model.label == alone.label == "GPT-4o [no-image]"
        assert model.intervals == alone.intervals


def test_only_runs_alike_in_everything_get_their_run_id(tmp_path):
    from lightemma.evaluation.core import unique_labels

    a, b = _run(tmp_path / "runs", seed=1), _run(tmp_path / "runs", seed=2)
    c = _run(tmp_path / "runs", seed=3, config={"inputs": "no-image"})
    labels = unique_labels([load_run(a), load_run(b), load_run(c)])
    assert labels == [f"GPT-4o [run {a.name}]", f"GPT-4o [run {b.name}]", "GPT-4o [no-image]"]
    named = [
        _run(tmp_path / "n", seed=1, name="x", config={"inputs": "no-image"}),
        _run(tmp_path / "n", seed=2, name="x", config={"inputs": "no-image"}),
    ]
    assert unique_labels([load_run(d) for d in named]) == [f'GPT-4o [no-image, run {d.name}] "x"' for d in named]


@pytest.mark.parametrize("name", ["a\x1bb", "r\u202el"])
def test_a_label_is_one_printable_line(tmp_path, name):
    from lightemma.evaluation.core import run_label

    run_dir = _run(tmp_path / "runs", name=name, display_name="GPT\n4o")
    assert (
        run_label(load_run(run_dir).info)
        == 'GPT\\n4o "' + name.replace("\x1b", "\\x1b").replace("\u202e", "\\u202e") + '"'
    )
