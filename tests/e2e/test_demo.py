"""`lightemma demo`: synthetic dataset → baseline runs → evaluation → report, end to end, offline."""

from __future__ import annotations

import os

os.environ.setdefault("MPLBACKEND", "Agg")

import json

import pytest

from lightemma.cli import main
from lightemma.errors import UserError
from lightemma.offline_demo import MARKER, api_models, run_demo, skipped_api_models, skipped_line


@pytest.mark.slow
def test_demo_end_to_end_in_the_current_directory(tmp_path, monkeypatch, capsys):
    for variable in ("OPENAI_API_KEY", "ANTHROPIC_API_KEY", "GEMINI_API_KEY"):
        monkeypatch.delenv(variable, raising=False)
    monkeypatch.chdir(tmp_path)
    assert main(["demo", "--keyframes", "15"]) == 0
    out = tmp_path / "lightemma-demo"
    index = out / "report" / "index.md"
    captured = capsys.readouterr()
    assert f"demo report: {index}" in captured.out
    # no key set: one line says which paper models were skipped and how to run them
    assert (
        "skipped paper models: gpt-4o (no key: set OPENAI_API_KEY), claude-3.7-sonnet (no key: set "
        "ANTHROPIC_API_KEY), gemini-2.0-flash (no key: set GEMINI_API_KEY)\n"
    ) in captured.err
    assert "frames: v1.0-mini, split all: 8 scenes, 8 frames, reference window" in captured.err
    # the ego baseline's fit on these few scenes is named as such, in one line of the demo's own (no Python warning)
    assert "\n    warning: baseline:ego is fitted on few frames: each fold's fit sees as few as " in captured.err
    assert "UserWarning" not in captured.err
    assert "scored in every run" not in captured.err  # no API model: every run has every frame
    text = index.read_text()
    # five baseline runs (the ego baseline cross-fitted over the 8 scenes), every frame scored, the oracle's floor visible
    evaluation = json.loads((out / "report" / "tables" / "evaluation.json").read_text())
    rows = {r["model"]: r for r in evaluation["accuracy"]["lightemma"]}
    assert (
        len(rows) == 5
        and "Baseline (ego status)" in rows
        and all(r["frames"] > 0 and r["frames"] == r["frames_in_run"] for r in rows.values())
    )
    oracle = [r for name, r in rows.items() if "oracle" in name]
    others = [r for name, r in rows.items() if "oracle" not in name]
    assert len(oracle) == 2 and max(r["ade_avg"] for r in oracle) < min(r["ade_avg"] for r in others)
    assert {r["fe_pct"] for r in rows.values()} == {0.0}  # baselines answer in the strict format
    # the safety columns: off-road on the synthetic map, collisions with its agents, the ground-truth floor at 0
    assert all(
        r["offroad"] is not None and r["collision"] is not None and r["area_source"] == "expansion"
        for r in rows.values()
    )
    assert (
        evaluation["safety"]["floor"]["lightemma"]["offroad"] == 0.0
        and evaluation["safety"]["floor"]["lightemma"]["collision"] == 0.0
    )
    assert "Off-road (%) [95% CI]" in text and "Collision (%) [95% CI]" in text and "| Ground truth (floor) |" in text
    # pictures drawn with the synthetic camera images (no "no camera view" note)
    assert "pictures have no camera view" not in text
    assert list((out / "report" / "figures" / "frames").glob("*_grid.png"))
    # a second demo into the same folder replaces the runs instead of piling them up; with a key
    # set, the API model runs too (here against a local OpenAI-compatible server)
    from tests.support.fake_openai import FakeOpenAIServer

    monkeypatch.setenv("OPENAI_API_KEY", "sk-test")
    said: list[str] = []
    with FakeOpenAIServer() as server:
        result = run_demo(out, scenes=2, keyframes=16, api_limit=2, api_base=server.url, log=said.append)
        assert server.requests  # the model was asked
    # two scenes: too few for the ego baseline's scene cross-fit, which is skipped with its reason
    assert set(result.skipped) == {"claude-3.7-sonnet", "gemini-2.0-flash", "baseline:ego"}
    assert "at least 3 scenes" in result.skipped["baseline:ego"]
    # the baselines, GPT-4o with all its inputs and again without the image
    assert len(list((out / "runs").glob("*/*/manifest.json"))) == 6 == len(result.run_dirs)
    evaluation = json.loads((out / "report" / "tables" / "evaluation.json").read_text())
    rows = {r["model"]: r for r in evaluation["accuracy"]["lightemma"]}
    assert rows["GPT-4o"]["frames_in_run"] == 2 and rows["Baseline (constant velocity)"]["frames_in_run"] == 4
    # like with like: the baselines ran on 4 frames, GPT-4o on the first 2, and every model is scored on those 2
    # (before: the baselines on their 4, GPT-4o on its 2, in one table); the demo and the report say so
    assert result.common and evaluation["common"] and evaluation["n_common"] == 2
    assert {r["frames"] for r in rows.values()} == {2} and {r["frames_accounted"] for r in rows.values()} == {2}
    assert any(
        "every model is scored on the frames scored in every run (the API models ran on the first 2 frames" in line
        for line in said
    )
    assert "2 frames scored in every run" in (out / "report" / "index.md").read_text()
    (ablation,) = evaluation["input_ablations"]
    assert (ablation["model"], ablation["ablation"], ablation["frames"]) == ("GPT-4o", "no-image", 2)
    assert {g["model"] for g in evaluation["baseline_gains"]} == {"GPT-4o", "GPT-4o [no-image]"}
    text = (out / "report" / "index.md").read_text()
    assert (
        "## Does the model look at the road?" in text
        and "Does the image matter?" in text
        and "Gain over the best baseline" in text
    )
    assert (out / "report" / "figures" / "input_ablations.png").stat().st_size > 1000


def test_demo_refuses_a_folder_it_did_not_make(tmp_path):
    (tmp_path / "mine.txt").write_text("precious")
    with pytest.raises(UserError, match="not a lightemma demo folder"):
        run_demo(tmp_path, use_api=False, log=lambda message: None)
    assert (tmp_path / "mine.txt").read_text() == "precious" and not (tmp_path / MARKER).exists()


def test_api_models_follow_the_keys_that_are_set():
    assert api_models({}) == []
    assert api_models({"ANTHROPIC_API_KEY": "x", "GEMINI_API_KEY": "", "OPENAI_API_KEY": "y"}) == [
        "gpt-4o",
        "claude-3.7-sonnet",
    ]


def test_skipped_models_name_the_missing_key_or_no_api():
    env = {"ANTHROPIC_API_KEY": "x", "GEMINI_API_KEY": ""}
    assert skipped_api_models(env) == {
        "gpt-4o": "no key: set OPENAI_API_KEY",
        "gemini-2.0-flash": "no key: set GEMINI_API_KEY",
    }
    assert skipped_line(skipped_api_models(env)) == (
        "skipped paper models: gpt-4o (no key: set OPENAI_API_KEY), gemini-2.0-flash (no key: set GEMINI_API_KEY)"
    )
    all_keys = {"OPENAI_API_KEY": "a", "ANTHROPIC_API_KEY": "b", "GEMINI_API_KEY": "c"}
    assert skipped_api_models(all_keys) == {}
    assert set(skipped_api_models(all_keys, use_api=False).values()) == {"--no-api"}


def test_demo_rejects_too_few_keyframes(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path / "d"), "--keyframes", "10"]) == 2
    assert "at least 15" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("flag", "value"), [("--scenes", "0"), ("--scenes", "-2"), ("--api-limit", "0"), ("--api-limit", "-1")]
)
def test_demo_refuses_a_count_below_one_before_any_work(tmp_path, capsys, flag, value):
    """Before: --scenes 0 ran the default 8 scenes, and --api-limit 0 ran a keyed API model on every frame."""
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), flag, value]) == 2
    assert capsys.readouterr().err.strip() == f"lightemma demo: error: {flag} must be at least 1, got {value}"
    assert not out.exists()


def test_demo_with_no_frame_common_to_every_run_says_so_and_scores_each_on_its_own(tmp_path, monkeypatch):
    """The API runs scored no frame in common (say, the full run and the no-image run failed on different frames):
    the report cannot compare on common frames, so each run is scored on its own frames and the demo warns."""
    from types import SimpleNamespace

    import lightemma
    import lightemma.frames.model
    import lightemma.report

    for variable in ("ANTHROPIC_API_KEY", "GEMINI_API_KEY"):
        monkeypatch.delenv(variable, raising=False)
    monkeypatch.setenv("OPENAI_API_KEY", "sk-test")
    monkeypatch.setattr(lightemma, "run", lambda model, **kw: SimpleNamespace(manifest={"dataset": {}}, run_dir=model))
    monkeypatch.setattr(lightemma.frames.model, "summary_line", lambda dataset: "stand-in")
    calls: list[bool] = []

    def report(run_dirs, out, *, common=False, **kw):
        calls.append(common)
        if common:
            raise UserError("no frame is valid for every run; nothing to compare with --common")
        return out / "index.md"

    monkeypatch.setattr(lightemma.report, "write_report", report)
    said: list[str] = []
    result = run_demo(tmp_path / "demo", scenes=1, keyframes=15, api_limit=1, log=said.append)
    assert calls == [True, False] and not result.common
    assert any(line.startswith("    warning: no frame is scored in every run") for line in said)
    # any other error of the report is not taken for this one

    def other(*args, **kwargs):
        raise UserError("other")

    monkeypatch.setattr(lightemma.report, "write_report", other)
    with pytest.raises(UserError, match="other"):
        run_demo(tmp_path / "demo", scenes=1, keyframes=15, api_limit=1, log=said.append)
