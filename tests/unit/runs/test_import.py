"""`lightemma import`: reference result folders become runs — checked, lossless where it matters, idempotent, atomic."""

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lightemma.cli import main
from lightemma.errors import UserError
from lightemma.evaluation import evaluate_runs
from lightemma.models.catalog import lookup, reference_model
from lightemma.models.prices import price_per_token
from lightemma.runs import importer
from lightemma.runs.importer import import_reference
from lightemma.runs.reference import as_stored, join_lines, split_lines
from lightemma.runs.store import find_run_dirs, read_manifest, read_run
from lightemma.runs.stored_prompts import call_prompt, frame_texts
from tests.support.reference_fixtures import (
    CALL_FAILED,
    PROMPT_SET,
    format_long_text,
    make_frame,
    write_results,
    write_scene,
)


@pytest.fixture
def results(tmp_path):
    return write_results(tmp_path / "results")


def imported(tmp_path, results, **kw):
    warnings = []
    out = import_reference([tmp_path / "results"], tmp_path / "runs", warn=warnings.append, **kw)
    return {r.model: r for r in out}, warnings


def test_one_run_per_model_named_by_the_registry_in_the_run_format(tmp_path, results):
    runs, _ = imported(tmp_path, results)
    assert set(runs) == {
        "gpt-4o",
        "claude-3.7-sonnet",
        "qwen-2.5-vl-7b",
        "my-finetune",
    }  # unknown names stay as they are
    for model, result in runs.items():
        assert result.outcome == "imported" and result.run_dir.parent == tmp_path / "runs" / model
        contents = read_run(result.run_dir)  # the store reads it as any run
        assert len(contents.records) == results["frames"][model] == result.frames and contents.complete
        manifest = contents.manifest
        source = results["models"][model]
        assert manifest["imported"]["from"] == os.fspath(source.resolve())
        assert manifest["imported"]["source_folder"] == source.name
        assert manifest["imported"]["registry_model"] == (None if model == "my-finetune" else model)
        assert manifest["dataset"]["window"] == "reference" and manifest["dataset"]["kind"] == "nuscenes"
        assert manifest["integrator"] == "euler" and manifest["params"]["parse"] == {"mode": "paper"}
    assert runs["claude-3.7-sonnet"].run_dir.parent.name == "claude-3.7-sonnet"  # the _<timestamp> suffix is dropped
    assert read_manifest(runs["claude-3.7-sonnet"].run_dir)["imported"]["source_model"] == "claude-3.7-sonnet"
    assert read_manifest(runs["my-finetune"].run_dir)["display_name"] == "my-finetune"
    # evaluate reads every imported run unchanged
    ev = evaluate_runs([tmp_path / "runs"])
    assert {row["model"] for row in ev.accuracy_rows()} == {
        "GPT-4o",
        "Claude-3.7-Sonnet",
        "Qwen-2.5-VL-7B",
        "my-finetune",
    }


def test_every_frame_field_comes_across(tmp_path, results):
    runs, _ = imported(tmp_path, results)
    source = json.loads(
        (results["models"]["gpt-4o"] / "output" / "scene-0002.json").read_text()
    )  # image_path only, no gt_actions
    contents = read_run(runs["gpt-4o"].run_dir)
    records, templates = contents.records, contents.manifest["prompt_set"]["templates"]
    assert set(templates) == {"scene", "intent", "actions"}  # each stage's shared text is stored once, in the manifest
    prices = price_per_token(lookup("gpt-4o"))
    for frame in source["frames"]:
        rec = records[f"scene-0002/{frame['sample_token']}"]
        ego, inf = frame["ego_info"], frame["inference"]
        assert rec["scene_name"] == "scene-0002" and rec["sample_token"] == frame["sample_token"]
        assert rec["keyframe_index"] == frame["frame_index"] + 7 and rec["timestamp"] == frame["timestamp"]
        assert rec["image_path"] == frame["image_path"] and rec["image_name"] == Path(frame["image_path"]).name
        assert rec["camera_params"] == frame["camera_params"]
        assert rec["history_actions"] == ego["obs_actions"] and rec["history_positions"] == ego["obs_positions"]
        assert rec["gt_positions"] == ego["gt_positions"] and rec["gt_actions"] is None
        assert (rec["ego_position"], rec["ego_heading"]) == (ego["position"], ego["heading"])
        (attempt,) = rec["attempts"]
        calls = {c["stage"]: c for c in attempt["calls"]}
        assert rec["scene_text"] == calls["scene"]["text"] == " ".join(inf["scene_description"])
        assert rec["intent_text"] == calls["intent"]["text"] == " ".join(inf["driving_intent"])
        assert rec["answer"] == attempt["answer"] == calls["actions"]["text"] == inf["pred_actions_str"]
        for stage, key in (("scene", "scene_prompt"), ("intent", "intent_prompt"), ("actions", "waypoint_prompt")):
            call = calls[stage]
            assert call_prompt(call, frame_texts(attempt["calls"]), templates) == " ".join(inf[key])
            assert (call["input_tokens"], call["output_tokens"]) == (
                frame["token_usage"][key]["input"],
                frame["token_usage"][key]["output"],
            )
            assert call["seconds"] == frame["time_usage"][key]
            assert call["cost_cents"] == pytest.approx(
                (call["input_tokens"] * prices[0] + call["output_tokens"] * prices[1]) * 100
            )
        assert rec["seconds"] == pytest.approx(sum(frame["time_usage"].values()))
        assert rec["input_tokens"] == sum(u["input"] for u in frame["token_usage"].values())
        assert rec["output_tokens"] == sum(u["output"] for u in frame["token_usage"].values())
        assert rec["cost_cents"] == pytest.approx(sum(c["cost_cents"] for c in attempt["calls"]))
        assert attempt["status"] == rec["status"] == rec["first_status"] and "failure" in attempt
    # image_name is kept as the file has it; local models have no price
    claude = read_run(runs["claude-3.7-sonnet"].run_dir).records
    assert all(
        r["image_name"].endswith(".jpg") and r["image_path"] is None
        for r in claude.values()
        if r["frame_id"].startswith("scene-0001")
    )
    assert all(
        r["cost_cents"] is None and r["input_tokens"] is not None
        for r in read_run(runs["my-finetune"].run_dir).records.values()
    )
    qwen = read_run(runs["qwen-2.5-vl-7b"].run_dir).records
    assert all(r["cost_cents"] is None for r in qwen.values())
    no_usage = [r for r in qwen.values() if r["source"] == {"file": "scene-0001.json", "frame_index": 1}]
    assert len(no_usage) == 1 and no_usage[0]["seconds"] is None and no_usage[0]["input_tokens"] is None


def test_the_reference_names_map_to_the_papers_rows():
    assert reference_model("claude-3.7").display_name == "Claude-3.7-Sonnet"
    assert reference_model("qwen2.5-7b").display_name == "Qwen-2.5-VL-7B"
    assert reference_model("LLaMA-3.2-11B").display_name == "LLaMA-3.2-11B"
    assert reference_model("gemini-2.5") is None  # the old scripts' "gemini-2.5" was 2.5 Pro, not a paper row
    assert reference_model("gpt-4.1") is None and reference_model("baseline:cv") is None


def test_a_folder_name_the_registry_does_not_know_falls_back_to_the_files_metadata(tmp_path):
    rng = np.random.default_rng(1)
    write_scene(
        tmp_path / "res" / "run-a",
        "scene-0001",
        [make_frame(rng, "scene-0001", i) for i in range(3)],
        metadata={"model": "claude-3.7"},
    )
    (result,) = import_reference([tmp_path / "res" / "run-a"], tmp_path / "runs")
    assert result.model == "claude-3.7-sonnet"
    assert read_manifest(result.run_dir)["imported"]["metadata_model"] == "claude-3.7"


@settings(max_examples=200, deadline=None)
@given(st.text(alphabet=st.sampled_from(list("abcdefghij XYZ.,;:-0123456789\n\t")), max_size=400))
def test_stage_texts_round_trip_through_the_references_lines(text):
    lines = split_lines(text)
    assert lines == format_long_text(text)  # the same splitting as the reference scripts
    assert all(len(line) <= 80 or " " not in line for line in lines)
    assert join_lines(lines) == as_stored(text)
    plain = " ".join(text.split())
    assert join_lines(format_long_text(plain)) == plain  # one-line texts with single spaces come back exactly


def test_importing_the_same_folder_again_writes_nothing(tmp_path, results, capsys):
    assert (
        main(["import", str(tmp_path / "results"), "--output", str(tmp_path / "runs"), "--quiet", "--jobs", "2"]) == 0
    )
    before = {p: p.stat().st_mtime_ns for p in (tmp_path / "runs").rglob("*")}
    capsys.readouterr()
    assert (
        main(
            [
                "import",
                str(tmp_path / "results" / "gpt-4o"),
                str(tmp_path / "results"),
                "--output",
                str(tmp_path / "runs"),
                "--quiet",
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert out.count("already imported") == 5 and "nothing written" in out
    assert {p: p.stat().st_mtime_ns for p in (tmp_path / "runs").rglob("*")} == before
    # a changed folder is a different source: a new run beside the old one
    rng = np.random.default_rng(3)
    write_scene(results["models"]["gpt-4o"], "scene-0009", [make_frame(rng, "scene-0009", i) for i in range(2)])
    (again,) = import_reference([results["models"]["gpt-4o"]], tmp_path / "runs")
    assert again.outcome == "imported" and again.frames == 15
    assert len(find_run_dirs(tmp_path / "runs" / "gpt-4o")) == 2


@pytest.mark.parametrize("error", [RuntimeError("disk trouble"), KeyboardInterrupt()])
def test_a_failure_mid_import_leaves_no_run(tmp_path, results, monkeypatch, error):
    original = importer._scene_records
    calls = []

    def failing(scene, *args):
        calls.append(scene.path.name)
        if len(calls) == 2:
            raise error
        return original(scene, *args)

    monkeypatch.setattr(importer, "_scene_records", failing)
    with pytest.raises(type(error)):
        import_reference([results["models"]["qwen-2.5-vl-7b"]], tmp_path / "runs")
    assert not (tmp_path / "runs").exists()  # no run, no partial folder, not even the folders made for it
    monkeypatch.setattr(importer, "_scene_records", original)
    (result,) = import_reference(
        [results["models"]["qwen-2.5-vl-7b"]], tmp_path / "runs"
    )  # and a retry imports it whole
    assert result.outcome == "imported" and result.frames == 21


def test_bad_files_and_frames_are_named_in_one_line_each_and_never_scored(tmp_path, results, capsys):
    assert main(["import", str(tmp_path / "results"), "--output", str(tmp_path / "runs"), "--jobs", "1"]) == 0
    captured = capsys.readouterr()
    warnings = [line for line in captured.err.splitlines() if line]
    assert all(line.startswith("lightemma import: warning: ") for line in warnings)
    (bad_file,) = [w for w in warnings if "scene-0003.json" in w]
    assert (
        str(results["bad_files"][0]) in bad_file and "not valid JSON" in bad_file and bad_file.endswith("file skipped")
    )
    for where in results["bad_frames"]["claude-3.7-sonnet"]:
        (line,) = [w for w in warnings if where in w]
        assert line.endswith("frame skipped")
    assert any("obs_actions[2]" in w and "finite" in w for w in warnings)
    assert any("gt_positions has 5 entries, expected 6" in w for w in warnings)
    claude = next(iter((tmp_path / "runs" / "claude-3.7-sonnet").iterdir()))
    sources = [r["source"] for r in read_run(claude).records.values()]
    assert {"file": "scene-0001.json", "frame_index": 5} not in sources and {
        "file": "scene-0004.json",
        "frame_index": 7,
    } not in sources
    imported_info = read_manifest(claude)["imported"]
    assert imported_info["frames_skipped"] == 2 and imported_info["files_skipped"] == []
    gpt = next(iter((tmp_path / "runs" / "gpt-4o").iterdir()))
    assert read_manifest(gpt)["imported"]["files_skipped"] == ["scene-0003.json"]
    assert "skipped 1 file(s)" in captured.out


def test_a_folder_without_a_usable_frame_writes_no_run_and_fails(tmp_path, capsys):
    folder = tmp_path / "res" / "gpt-4o" / "output"
    folder.mkdir(parents=True)
    (folder / "scene-0001.json").write_text('{"frames": [{"sample_token": "x"}]}')
    assert main(["import", str(tmp_path / "res"), "--output", str(tmp_path / "runs"), "--quiet"]) == 1
    captured = capsys.readouterr()
    assert (
        "no usable frame" in captured.out
        and "scene-0001.json frame #0: no ego_info object; frame skipped" in captured.err
    )
    assert not (tmp_path / "runs").exists()


def test_a_failed_call_stored_as_text_is_an_api_error_not_a_format_error(tmp_path):
    rng = np.random.default_rng(5)
    frames = [make_frame(rng, "scene-0001", i, answer=CALL_FAILED if i == 1 else None) for i in range(4)]
    frames[1]["token_usage"]["waypoint_prompt"] = {"input": 0, "output": 0}
    write_scene(tmp_path / "res" / "gpt-4o", "scene-0001", frames)
    (result,) = import_reference([tmp_path / "res"], tmp_path / "runs")
    rec = next(r for r in read_run(result.run_dir).records.values() if r["source"]["frame_index"] == 1)
    call = rec["attempts"][0]["calls"][2]
    assert rec["status"] == "failed" and rec["answer"] is None and rec["failure"] == "api_error"
    assert call["text"] is None and call["error"] == "ReferenceCallError" and call["error_message"] == CALL_FAILED
    assert (
        result.summary["api_errors"] == 1
        and result.summary["answers_received"] == 3
        and result.summary["fe_percent"] == 0.0
    )


def test_source_errors_are_one_line(tmp_path, capsys):
    assert main(["import", str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("lightemma import: error:") and "nowhere" in err and "\n" not in err
    (tmp_path / "empty").mkdir()
    with pytest.raises(UserError, match="holds no reference results"):
        import_reference([tmp_path / "empty"], tmp_path / "runs")


def test_an_imported_run_cannot_be_resumed(tmp_path, results):
    from lightemma import resume

    runs, _ = imported(tmp_path, results)
    with pytest.raises(UserError, match="not written by `lightemma run`"):
        resume(runs["gpt-4o"].run_dir)


def test_the_fixture_prompt_set_is_a_valid_prompt_set():
    from lightemma.prompts import PromptSet

    assert PromptSet.from_dict(PROMPT_SET).name == "fixture-reference"


def test_parallel_import_writes_the_same_runs_and_warnings(tmp_path, results):
    serial, warned = [], []
    one = import_reference([tmp_path / "results"], tmp_path / "one", warn=serial.append, jobs=1)
    two = import_reference([tmp_path / "results"], tmp_path / "two", warn=warned.append, jobs=2)
    assert [r.model for r in one] == [r.model for r in two] and serial == warned
    for a, b in zip(one, two):
        assert a.run_dir.name == b.run_dir.name
        assert (a.run_dir / "frames.jsonl").read_bytes() == (b.run_dir / "frames.jsonl").read_bytes()


def test_actions_too_large_to_integrate_are_named_and_never_scored(tmp_path):
    huge = "[" + ", ".join([f"({'9' * 308}, 0)"] * 6) + "]"  # a Python literal: the paper's rules read it as ok
    rng = np.random.default_rng(2)
    write_scene(
        tmp_path / "res" / "gpt-4o",
        "scene-0001",
        [make_frame(rng, "scene-0001", i, answer=huge if i == 0 else None) for i in range(3)],
    )
    warnings = []
    (result,) = import_reference([tmp_path / "res"], tmp_path / "runs", warn=warnings.append)
    assert any("non-finite positions" in w and "frame 0" in w for w in warnings)
    rec = next(r for r in read_run(result.run_dir).records.values() if r["source"]["frame_index"] == 0)
    assert rec["status"] == "ok" and rec["trajectory"] is None
    (row,) = evaluate_runs([result.run_dir]).accuracy_rows()
    assert row["frames"] == 2 and math.isfinite(row["ade_avg"])


def test_a_stored_trajectory_that_disagrees_with_the_answer_is_reported(tmp_path):
    rng = np.random.default_rng(4)
    frames = [make_frame(rng, "scene-0001", i) for i in range(3)]
    frames[2]["predictions"]["trajectory"][5][0] += 0.5  # the file's own integration differs from its answer's
    write_scene(tmp_path / "res" / "gpt-4o", "scene-0001", frames)
    warnings = []
    import_reference([tmp_path / "res"], tmp_path / "runs", warn=warnings.append)
    (line,) = warnings
    assert "scene-0001.json: 1 frame(s) whose stored predictions.trajectory differs" in line and "0.5 m" in line
