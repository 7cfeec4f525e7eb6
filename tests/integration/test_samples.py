"""K samples per frame (--samples K --temperature T): records, minADE@K / minFDE@K, resume, estimate, refusals.

Against the loopback OpenAI server (tests/support/fake_openai.py) with a scripted model whose answer depends on the sample:
stage 1 answers a request with ``n`` with n different scenes ("Scene variant i."), and the later stages answer from
the scene pasted into their prompt, so sample i drives at 4 + i m/s.
"""

from __future__ import annotations

import re
import sqlite3
import threading
from pathlib import Path

import numpy as np
import pytest

from lightemma.backends.api import APIBackend
from lightemma.errors import RunStopped, UserError
from lightemma.evaluation.core import evaluate_runs
from lightemma.pipeline.config import InvalidSetting, RunConfig
from lightemma.pipeline.runner import estimate_run, resume, run
from lightemma.runs.store import read_run
from tests.support.fake_openai import FakeOpenAIServer, Reply

KEY = "LIGHTEMMA_TEST_SAMPLES_KEY"
K = 3


@pytest.fixture(autouse=True)
def key(monkeypatch):
    monkeypatch.setenv(KEY, "sk-test-samples")


def _variant(text: str) -> int:
    found = re.search(r"Scene variant (\d+)", text)
    assert found, text[:200]
    return int(found.group(1))


def sampled_model(req) -> Reply:
    """Stage 1: one scene per requested answer (n); later stages follow the scene their prompt carries."""
    if req.stage == "scene":
        return Reply(choices=[f"Scene variant {i}." for i in range(req.body.get("n", 1))])
    j = _variant(req.text)
    if req.stage == "intent":
        return Reply(f"Keep the lane, variant {j}.")
    return Reply("[" + ", ".join(f"({4.0 + j}, 0.0)" for _ in range(6)) + "]")


def _run(synth_root, tmp_path, server, **kw):
    settings = dict(
        dataroot=synth_root,
        version="v1.0-mini",
        split="all",
        api_base=server.url,
        api_key_env=KEY,
        output=tmp_path / "runs",
        limit=2,
        progress=False,
        samples=K,
        temperature=0.7,
        concurrency=1,
        cache=str(tmp_path / "cache.sqlite"),
    )
    settings.update(kw)
    return run("openai/gpt-4o", **settings)


def test_three_samples_are_three_recorded_chains_with_stage_1_asked_once_with_n(synth_root, tmp_path):
    with FakeOpenAIServer(sampled_model) as server:
        result = _run(synth_root, tmp_path, server, cache=None)
    scenes = [r for r in server.requests if r.stage == "scene"]
    assert [r.body.get("n") for r in scenes] == [K, K]  # one request per frame draws every sample's scene
    assert all("n" not in r.body for r in server.requests if r.stage != "scene")
    assert all(r.body["temperature"] == 0.7 for r in server.requests)
    assert len(server.requests) == 2 * (1 + 2 * K)
    contents = read_run(result.run_dir)
    assert contents.manifest["params"]["samples"] == K and contents.manifest["config"]["samples"] == K
    for record in contents.records.values():
        assert record["scene_text"] == "Scene variant 0." and record["status"] == "ok"  # sample 0 where it always was
        assert [s["sample"] for s in record["samples"]] == [1, 2]
        speeds = [record["actions"][0][0]] + [s["actions"][0][0] for s in record["samples"]]
        assert speeds == [4.0, 5.0, 6.0]
        assert [s["scene_text"] for s in record["samples"]] == ["Scene variant 1.", "Scene variant 2."]
        # the frame's tokens count every sample's calls: the n request once (1000), then 2 calls per sample
        own = [c["input_tokens"] for a in record["attempts"] for c in a["calls"]]
        others = [c["input_tokens"] for s in record["samples"] for a in s["attempts"] for c in a["calls"]]
        shared = [a["calls"][0]["input_tokens"] for s in record["samples"] for a in s["attempts"]]
        assert own[0] == 1000 and shared == [0, 0]
        assert record["input_tokens"] == sum(own) + sum(others) == 1000 * (1 + 2 * K)


def test_min_ade_and_min_fde_are_the_best_of_the_recorded_samples(synth_root, tmp_path):
    with FakeOpenAIServer(sampled_model) as server:
        result = _run(synth_root, tmp_path, server)
    records = list(read_run(result.run_dir).records.values())
    ade, fde, best_ade, best_fde, spread = [], [], [], [], []
    for record in records:
        gt = np.array(record["gt_positions"])
        trajs = [np.array(record["trajectory"])] + [np.array(s["trajectory"]) for s in record["samples"]]
        errors = [np.linalg.norm(t - gt, axis=1) for t in trajs]  # e_1 … e_6 per sample
        ade.append(errors[0].mean())
        fde.append(errors[0][-1])
        best_ade.append(min(e.mean() for e in errors))
        best_fde.append(min(e[-1] for e in errors))
        finals = [t[-1] for t in trajs]
        spread.append(np.mean([np.linalg.norm(finals[i] - finals[j]) for i in range(K) for j in range(i + 1, K)]))
    evaluation = evaluate_runs([result.run_dir], safety=False, planning=False, explanations=False)
    row = evaluation.accuracy_rows()[0]
    assert row["samples"] == K and row["frames"] == 2
    assert row["ade_avg"] == pytest.approx(np.mean(ade)) and row["fde"] == pytest.approx(np.mean(fde))
    assert row["minade"] == pytest.approx(np.mean(best_ade)) and row["minfde"] == pytest.approx(np.mean(best_fde))
    assert row["minade"] < row["ade_avg"]  # the samples differ: the best of three beats sample 0
    assert row["spread_m"] == pytest.approx(np.mean(spread))
    assert "minade" in evaluation.to_dict()["accuracy"]["lightemma"][0]
    from lightemma.report.evaluation_tables import accuracy_table

    headers = [c.header for c in accuracy_table(evaluation, "lightemma").columns]
    assert headers[headers.index("FDE (m) [95% CI]") + 1 :][:3] == ["K", "minADE@K (m)", "minFDE@K (m)"]


def test_evaluate_json_carries_minade_with_its_descriptor_and_passes_the_schema(synth_root, tmp_path, capsys):
    import json

    import jsonschema

    from lightemma.cli import main

    with FakeOpenAIServer(sampled_model) as server:
        result = _run(synth_root, tmp_path, server, limit=1)
    capsys.readouterr()
    assert main(["evaluate", str(result.run_dir), "--resamples", "0", "--format", "json", "--convention", "all"]) == 0
    doc = json.loads(capsys.readouterr().out)
    schema = json.loads((Path(lightemma_root()) / "evaluation" / "schema.json").read_text())
    assert sorted(e.message for e in jsonschema.Draft202012Validator(schema).iter_errors(doc)) == []
    tables = {t["name"]: t for t in doc["tables"]}
    assert tables["accuracy_stp3"]["rows"][0]["samples"] == K
    described = doc["columns"]["accuracy_stp3"]
    assert described["minade"]["id"] == "minade@stp3/1" and described["minfde"]["id"] == "minfde/1"
    assert doc["columns"]["accuracy_lightemma"]["minade"]["id"] == "minade@lightemma/1"
    for name, table in tables.items():  # every emitted column has a descriptor
        keys = {k for row in table["rows"] for k in row}
        assert [k for k in sorted(keys) if doc["columns"][name].get(k) is None] == [], name


def lightemma_root():
    import lightemma

    return Path(lightemma.__file__).parent


def test_safety_and_planning_of_the_best_sample_and_the_mean_trajectory(synth_root, tmp_path):
    with FakeOpenAIServer(sampled_model) as server:
        result = _run(synth_root, tmp_path, server)
    evaluation = evaluate_runs([result.run_dir], explanations=False)
    row = evaluation.accuracy_rows()[0]
    own = {key: row[key] for key in row["best"] if key in row}
    assert set(row["best"]) == set(row["mean"]) and own  # the run's own safety / planning keys
    one = evaluate_runs([_one_sample_copy(result.run_dir, tmp_path)], explanations=False).accuracy_rows()[0]
    assert {k: one.get(k) for k in row["best"] if k in one} == {k: v for k, v in row["best"].items() if k in one}


def _one_sample_copy(run_dir, tmp_path):
    """The run with each frame's trajectory replaced by its best sample (by ADE avg), as a one-sample run."""
    import json
    import shutil

    copy = tmp_path / "copy" / run_dir.parent.name / run_dir.name
    shutil.copytree(run_dir, copy)
    (copy / "frames.columns.npz").unlink(missing_ok=True)
    manifest = json.loads((copy / "manifest.json").read_text())
    del manifest["params"]["samples"]
    (copy / "manifest.json").write_text(json.dumps(manifest))
    lines = []
    for line in (copy / "frames.jsonl").read_text().splitlines():
        record = json.loads(line)
        gt = np.array(record["gt_positions"])
        options = [record] + record.pop("samples")
        best = min(options, key=lambda o: np.linalg.norm(np.array(o["trajectory"]) - gt, axis=1).mean())
        record["trajectory"], record["actions"] = best["trajectory"], best["actions"]
        lines.append(json.dumps(record))
    (copy / "frames.jsonl").write_text("\n".join(lines) + "\n")
    return copy


def test_k_calls_where_the_provider_takes_no_n_each_sample_its_own_cache_row(synth_root, tmp_path, monkeypatch):
    monkeypatch.setattr(APIBackend, "sampling", lambda self: "calls")
    count = {"scene": 0}
    lock = threading.Lock()

    def model(req) -> Reply:
        if req.stage == "scene":
            assert "n" not in req.body
            with lock:
                count["scene"] += 1
                i = (count["scene"] - 1) % K
            return Reply(f"Scene variant {i}.")
        return sampled_model(req)

    with FakeOpenAIServer(model) as server:
        result = _run(synth_root, tmp_path, server, limit=1)
    assert count["scene"] == K and len(server.requests) == 3 * K
    with sqlite3.connect(tmp_path / "cache.sqlite") as db:
        assert db.execute("SELECT COUNT(*) FROM responses").fetchone()[0] == 3 * K  # one row per sample and stage
    (record,) = read_run(result.run_dir).records.values()
    texts = [record["scene_text"]] + [s["scene_text"] for s in record["samples"]]
    assert sorted(texts) == [f"Scene variant {i}." for i in range(K)]


def test_a_resume_after_a_stop_continues_the_missing_samples_from_the_cache(synth_root, tmp_path):
    answered = {"actions": 0, "fail": True}
    lock = threading.Lock()

    def failing(req) -> Reply:
        if req.stage == "actions" and answered["fail"]:
            with lock:
                answered["actions"] += 1
                if answered["actions"] > 1:  # one sample's stage 3 answered, then the key is rejected
                    return Reply.error(401, "invalid key")
        return sampled_model(req)

    with FakeOpenAIServer(failing) as server:
        with pytest.raises(RunStopped):
            _run(synth_root, tmp_path, server, limit=1)
        (run_dir,) = [p.parent for p in (tmp_path / "runs").glob("*/*/manifest.json")]
        assert len(read_run(run_dir).records) == 0  # the frame was cut off mid-chain: not written
        answered["fail"] = False
        before = len(server.requests)
        done = resume(
            run_dir, progress=False, api_base=server.url, api_key_env=KEY, cache=str(tmp_path / "cache.sqlite")
        )
        again = server.requests[before:]
    # stages 1 and 2 of every sample and one sample's stage 3 come from the cache: only the two missing answers go out
    assert [r.stage for r in again] == ["actions", "actions"]
    (record,) = read_run(done.run_dir).records.values()
    speeds = [record["actions"][0][0]] + [s["actions"][0][0] for s in record["samples"]]
    assert speeds == [4.0, 5.0, 6.0] and record["cached_calls"] == 3 * K - 2


def test_the_estimate_and_max_cost_count_k_chains_per_frame(synth_root, tmp_path):
    import lightemma

    frames = lightemma.load_frames(synth_root, "v1.0-mini", split="all")
    one, three = estimate_run("gpt-4o", frames=frames), estimate_run("gpt-4o", frames=frames, samples=K)
    assert three.calls == K * one.calls and three.output_tokens == K * one.output_tokens
    assert three.input_tokens == K * one.input_tokens and three.cost_cents == pytest.approx(K * one.cost_cents)
    assert f"{len(frames)} frames × {K} samples" in three.line() and "samples" not in one.to_dict()
    per_frame = one.cost_cents / len(frames)
    with FakeOpenAIServer(sampled_model) as server:
        # a limit that admits one chain of a frame but not three: refused before anything is written or sent
        with pytest.raises(UserError, match=rf"{3 * K} calls \({K} samples\)"):
            _run(synth_root, tmp_path, server, price=(2.5, 10.0), max_cost_cents=1.5 * per_frame)
    assert server.requests == [] and not (tmp_path / "runs").exists()


def test_max_cost_admits_a_frame_at_its_k_chains_and_stops_before_the_next(synth_root, tmp_path):
    import lightemma

    frames = lightemma.load_frames(synth_root, "v1.0-mini", split="all")
    per_call = estimate_run("gpt-4o", frames=frames.head(2), price=(2.5, 10.0)).cents_per_call
    limit = 1.2 * 3 * K * per_call  # one frame's K chains fit; after its spending the next frame's do not
    with FakeOpenAIServer(sampled_model) as server, pytest.raises(RunStopped) as stopped:
        _run(synth_root, tmp_path, server, cache=None, price=(2.5, 10.0), max_cost_cents=limit)
    assert "--max-cost" in str(stopped.value)
    (run_dir,) = [p.parent for p in (tmp_path / "runs").glob("*/*/manifest.json")]
    assert len(read_run(run_dir).records) == 1 and len(server.requests) == 1 + 2 * K


@pytest.mark.parametrize(
    ("value", "message"),
    [
        (0, "samples must be at least 1, got 0"),
        (2.5, "samples must be a whole number, got 2.5"),
        (True, "samples must be a whole number"),
        (65, "samples must be between 1 and 64, got 65"),
    ],
)
def test_bad_sample_counts_are_refused_naming_the_setting(value, message):
    with pytest.raises(InvalidSetting, match=re.escape(message)):
        RunConfig.of("openai/gpt-4o", samples=value)


def test_one_sample_keeps_the_manifest_blocks_as_they_were():
    config = RunConfig.of("openai/gpt-4o")
    assert "samples" not in config.to_manifest() and config.prompting.samples == 1
    assert RunConfig.from_manifest(config.to_manifest()).prompting.samples == 1
    sampled = RunConfig.of("openai/gpt-4o", samples=K, temperature=0.7)
    assert RunConfig.from_manifest(sampled.to_manifest()).prompting == sampled.prompting


def test_the_cli_refuses_bad_samples_and_a_baseline_that_cannot_sample(synth_root, tmp_path, capsys):
    from lightemma.cli import main

    common = [
        "run",
        "--dataroot",
        str(synth_root),
        "--version",
        "v1.0-mini",
        "--split",
        "all",
        "--output",
        str(tmp_path),
        "--no-progress",
    ]
    assert main([*common, "--model", "openai/gpt-4o", "--samples", "0"]) != 0
    assert "--samples must be at least 1, got 0" in capsys.readouterr().err
    assert main([*common, "--model", "baseline:cv", "--samples", "2", "--temperature", "0.5"]) != 0
    err = capsys.readouterr().err
    assert "--samples 2: the baseline" in err and "cannot sample" in err and len(err.strip().splitlines()) == 1
    assert not list(tmp_path.glob("*/*/manifest.json"))  # nothing written


def test_temperature_0_with_k_samples_warns_and_runs(synth_root, tmp_path):
    lines: list[str] = []
    with FakeOpenAIServer(sampled_model) as server:
        result = _run(synth_root, tmp_path, server, temperature=0.0, limit=1, log=lines.append)
    assert any(line.startswith(f"warning: --samples {K} at --temperature 0") for line in lines)
    (record,) = read_run(result.run_dir).records.values()
    assert len(record["samples"]) == K - 1


@pytest.mark.slow
def test_the_hf_backend_draws_k_samples_with_k_sampled_generate_requests(synth_root, tmp_path):
    pytest.importorskip("torch")
    from tests.support.local_models import build_tiny_model

    path = build_tiny_model("qwen2_vl", tmp_path / "tiny")
    result = run(
        str(path),
        backend="hf",
        dataroot=synth_root,
        version="v1.0-mini",
        split="all",
        output=tmp_path / "runs",
        limit=1,
        progress=False,
        samples=2,
        temperature=1.0,
        max_tokens=6,
        max_attempts=1,
    )
    (record,) = read_run(result.run_dir).records.values()
    assert result.manifest["params"]["samples"] == 2 and [s["sample"] for s in record["samples"]] == [1]
    calls = [record["attempts"][0]["calls"][0], record["samples"][0]["attempts"][0]["calls"][0]]
    assert [c["stage"] for c in calls] == ["scene", "scene"] and all(isinstance(c["text"], str) for c in calls)
    assert result.manifest["params"]["sent"] is None or result.manifest["params"]["sent"].get("temperature") == 1.0
