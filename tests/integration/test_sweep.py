"""lightemma sweep: variants over the same frames against the loopback server; the sweep manifest, resume, refusals,
the whole sweep's estimate and --max-cost; the robustness table's paired differences against a hand computation."""

import base64
import io
import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from lightemma.cli import main as cli_main
from lightemma.errors import RunStopped, UserError
from lightemma.pipeline.variant_sweep import SWEEP_FILE, parse_variants, sweep
from tests.support.fake_openai import FakeOpenAIServer, Reply, default_reply

FAST = dict(backoff_base=0.01, timeout=10.0, progress=False)
MODEL = "openai/gpt-4o"
VARIANTS = "clean,corrupt:fog@5,no-image"


class Driver:
    """A model whose speed follows the image it is shown: brighter (fog) is faster, no image is slowest; with
    ``fail_without_image`` a request without an image is refused with a 401 (a run-fatal stop)."""

    def __init__(self):
        self.fail_without_image = False

    def __call__(self, req):
        images = [p["data"] for _, turn in req.messages() for p in turn if p["kind"] == "image"]
        if not images and self.fail_without_image:
            return Reply.error(401, "bad key")
        if req.stage != "actions":
            return default_reply(req)
        if images:
            rgb = np.asarray(Image.open(io.BytesIO(base64.b64decode(images[0]))).convert("RGB"), dtype=np.float64)
            speed = 3.0 + rgb.mean() / 50.0
        else:
            speed = 2.0
        return Reply("[" + ", ".join(f"({speed + 0.1 * k:.4f}, 0.0)" for k in range(6)) + "]")


def run_sweep(server, out, synth_root, inputs=VARIANTS, **kw):
    return sweep(
        MODEL,
        inputs=inputs,
        out=out,
        dataroot=synth_root,
        version="v1.0-mini",
        sample=kw.pop("sample", 6),
        api_base=server.url,
        **FAST,
        **kw,
    )


def records(run_dir):
    with open(Path(run_dir) / "frames.jsonl", encoding="utf-8") as fh:
        return {r["frame_id"]: r for r in map(json.loads, fh)}


def hand_ade(record):
    """ADE avg (lightemma convention) of one record: the mean of the six per-step L2 errors."""
    pred, gt = np.array(record["trajectory"], dtype=np.float64), np.array(record["gt_positions"], dtype=np.float64)
    return float(np.linalg.norm(pred - gt, axis=1).mean())


def test_variants_run_over_the_same_frames_linked_in_the_sweep_manifest_and_a_rerun_skips_them(tmp_path, synth_root):
    out = tmp_path / "sweep"
    with FakeOpenAIServer(Driver()) as server:
        result = run_sweep(server, out, synth_root)
        first = len(server.requests)
        again = run_sweep(server, out, synth_root)
        assert len(server.requests) == first  # every variant finished: nothing is sent again
    assert first == 3 * 6 * 3  # 3 variants × 6 frames × 3 stages
    manifest = json.loads((out / SWEEP_FILE).read_text())
    assert manifest["format"] == "lightemma-sweep/1" and manifest["model"] == MODEL
    assert [v["variant"] for v in manifest["variants"]] == ["clean", "corrupt:fog@5", "no-image"]
    assert [v["status"] for v in manifest["variants"]] == ["finished"] * 3
    assert manifest["frame_set"]["n_frames"] == 6 and manifest["dataset"]["sample"] == {"n": 6, "seed": 0}
    ids = []
    for entry in manifest["variants"]:
        run_dir = out / entry["run_dir"]
        assert (run_dir / "manifest.json").is_file() and entry["run_dir"].split("/")[0] == entry["folder"]
        run_manifest = json.loads((run_dir / "manifest.json").read_text())
        assert run_manifest["config"]["inputs"] == entry["inputs"]
        ids.append(sorted(records(run_dir)))
    assert ids[0] == ids[1] == ids[2] and len(ids[0]) == 6
    assert {v["inputs"] for v in manifest["variants"]} == {"full", "corrupt:fog@5", "no-image"}
    assert set(result.runs) == {"clean", "corrupt:fog@5", "no-image"} and all(
        r is not None for r in result.runs.values()
    )
    assert all(r is None for r in again.runs.values())  # skipped
    assert "skipped (finished before)" in again.report()


def test_a_stopped_variant_is_resumed_in_its_own_run_and_finished_ones_are_skipped(tmp_path, synth_root):
    out = tmp_path / "sweep"
    driver = Driver()
    driver.fail_without_image = True
    with FakeOpenAIServer(driver) as server:
        with pytest.raises(RunStopped):
            run_sweep(server, out, synth_root)
        manifest = json.loads((out / SWEEP_FILE).read_text())
        status = {v["variant"]: v["status"] for v in manifest["variants"]}
        assert status == {"clean": "finished", "corrupt:fog@5": "finished", "no-image": "stopped"}
        stopped_dir = manifest["variants"][2]["run_dir"]
        assert stopped_dir and (out / stopped_dir / "manifest.json").is_file()
        driver.fail_without_image = False
        before = len(server.requests)
        result = run_sweep(server, out, synth_root)
        resumed = server.requests[before:]
    assert resumed and not any(r.has_image for r in resumed)  # only the no-image variant was sent again
    assert result.runs["clean"] is None and result.runs["corrupt:fog@5"] is None
    manifest = json.loads((out / SWEEP_FILE).read_text())
    assert [v["status"] for v in manifest["variants"]] == ["finished"] * 3
    assert manifest["variants"][2]["run_dir"] == stopped_dir  # the same run, resumed
    assert len(list((out / "no-image").glob("*/*/manifest.json"))) == 1
    assert len(records(out / stopped_dir)) == 6 and all(
        r["status"] == "ok" for r in records(out / stopped_dir).values()
    )


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (dict(inputs="clean,corrupt:fog@5"), "the variants differ from the sweep's"),
        (dict(inputs="clean,no-image,corrupt:fog@5"), "the variants differ from the sweep's"),
        (dict(sample=5), "the frame set differs from the sweep's (sample"),
        (dict(temperature=0.5), "the setting temperature differs"),
    ],
)
def test_a_changed_variant_list_frame_set_or_setting_is_refused_in_one_line(tmp_path, synth_root, change, expected):
    out = tmp_path / "sweep"
    with FakeOpenAIServer(Driver()) as server:
        run_sweep(server, out, synth_root, inputs="clean,corrupt:fog@5,no-image", sample=4)
        before = (out / SWEEP_FILE).read_text()
        sent = len(server.requests)
        kw = {"sample": 4, **change}
        with pytest.raises(UserError) as info:
            run_sweep(server, out, synth_root, **kw)
        assert len(server.requests) == sent
    message = str(info.value)
    assert expected in message and "\n" not in message and str(out) in message
    assert (out / SWEEP_FILE).read_text() == before


@pytest.mark.parametrize(
    ("inputs", "expected"),
    [
        ("clean,corrupt:haze@3", "unknown corruption 'haze'"),
        ("clean,corrupt:fog@6", "severity must be an integer 1-5"),
        ("clean,bogus", "variant 'bogus'"),
        ("clean,corrupt:fog@3,corrupt:fog@3", "'corrupt:fog@3' is given twice"),
        ("clean,full", "'full' (as clean) is given twice"),
        ("history-noise@0.5,0.01,history-noise@0.50,0.010", "is given twice"),
        ("corrupt:fog@3,no-image", "no clean variant"),
        ("clean,,no-image", "an empty variant"),
    ],
)
def test_bad_variants_are_one_line_before_any_call_and_nothing_is_written(
    tmp_path, synth_root, capsys, inputs, expected
):
    with FakeOpenAIServer(Driver()) as server:
        with pytest.raises(UserError) as info:
            run_sweep(server, tmp_path / "lib", synth_root, inputs=inputs)
        code = cli_main(
            [
                "sweep",
                "--model",
                MODEL,
                "--inputs",
                inputs,
                "--out",
                str(tmp_path / "cli"),
                "--dataroot",
                str(synth_root),
                "--version",
                "v1.0-mini",
                "--api-base",
                server.url,
                "--no-progress",
            ]
        )
        assert server.requests == []
    assert expected in str(info.value) and "\n" not in str(info.value)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and expected in err[0] and err[0].startswith("lightemma sweep: error:"), err
    assert not (tmp_path / "lib").exists() and not (tmp_path / "cli").exists()


def test_parse_variants_keeps_a_history_noise_comma_and_canonicalises():
    assert parse_variants("full,history-noise@0.50,0.010,history-stale@2") == [
        "clean",
        "history-noise@0.5,0.01",
        "history-stale@2",
    ]
    assert parse_variants(["clean", "corrupt:fog@1"]) == ["clean", "corrupt:fog@1"]


def test_one_estimate_for_the_whole_sweep_and_max_cost_bounds_the_whole_sweep(tmp_path, synth_root, capsys):
    from lightemma.pipeline.runner import estimate_run
    from lightemma.pipeline.variant_sweep import _load

    with FakeOpenAIServer(Driver()) as server:
        code = cli_main(
            [
                "sweep",
                "--model",
                MODEL,
                "--inputs",
                VARIANTS,
                "--out",
                str(tmp_path / "est"),
                "--dataroot",
                str(synth_root),
                "--version",
                "v1.0-mini",
                "--sample",
                "6",
                "--api-base",
                server.url,
                "--estimate",
            ]
        )
        printed = capsys.readouterr().out
        assert code == 0 and not (tmp_path / "est").exists() and server.requests == []
        # the total is the sum of the per-variant estimates
        _, frames = _load(
            {
                "dataroot": str(synth_root),
                "version": "v1.0-mini",
                "split": None,
                "scenes": None,
                "window": "reference",
                "limit": None,
                "sample": {"n": 6, "seed": 0},
                "on_bad_record": "skip",
            },
            None,
        )
        parts = [
            estimate_run(MODEL, frames=frames, inputs=i, api_base=server.url)
            for i in ("full", "corrupt:fog@5", "no-image")
        ]
        total = sum(p.cost_cents for p in parts)
        assert printed.splitlines()[0].startswith(
            f"sweep estimate: 3 variant(s) to run, 18 frame runs, 54 calls: ~${total / 100:,.2f} normal"
        )
        assert len(printed.splitlines()) == 4
        # --max-cost below the whole sweep (each variant alone would fit): refused, nothing sent or written
        limit = total * 0.9
        assert all(p.cost_cents < limit for p in parts)
        with pytest.raises(UserError) as info:
            run_sweep(server, tmp_path / "over", synth_root, max_cost_cents=limit)
        assert server.requests == [] and not (tmp_path / "over").exists()
        assert "nothing was run" in str(info.value) and "\n" not in str(info.value)
        # within it: the sweep runs, and what it spent stays within the limit
        result = run_sweep(server, tmp_path / "within", synth_root, max_cost_cents=total * 2)
    spent = sum(
        float(r.get("cost_cents") or 0)
        for e in result.manifest["variants"]
        for r in records(tmp_path / "within" / e["run_dir"]).values()
    )
    assert 0 < spent <= total * 2


def test_the_robustness_table_pairs_each_variant_with_the_clean_run_as_a_hand_computation(tmp_path, synth_root):
    from lightemma.evaluation import evaluate_runs
    from lightemma.evaluation.stats import Resampling, holm

    out = tmp_path / "sweep"
    with FakeOpenAIServer(Driver()) as server:
        result = run_sweep(server, out, synth_root, sample=8)
    evaluation = evaluate_runs([out], resampling=Resampling(n_resamples=200), explanations=False)
    rob = evaluation.robustness
    assert rob is not None and [r["variant"] for r in rob.rows] == ["corrupt:fog@5", "no-image"]
    assert rob.to_dict()["metrics"]["ade_avg"] == "ade@lightemma/1"
    clean = records(out / result.manifest["variants"][0]["run_dir"])
    for row, entry in zip(rob.rows, result.manifest["variants"][1:], strict=True):
        mine = records(out / entry["run_dir"])
        common = sorted(set(clean) & set(mine))
        hand = np.array([hand_ade(mine[f]) - hand_ade(clean[f]) for f in common])
        assert row["frames"] == len(common) == 8
        assert row["ade_avg_diff"] == pytest.approx(hand.mean(), abs=1e-9)
        assert row["ade_avg_clean"] == pytest.approx(np.mean([hand_ade(clean[f]) for f in common]), abs=1e-9)
        assert row["ade_avg_variant"] == pytest.approx(np.mean([hand_ade(mine[f]) for f in common]), abs=1e-9)
        assert abs(row["ade_avg_diff"]) > 0.01  # the driver's speed follows the image: the variants differ
        low, high = row["ade_avg_ci95"]
        assert low <= row["ade_avg_diff"] <= high
    assert [r["ade_avg_p_holm"] for r in rob.rows] == pytest.approx(list(holm([r["ade_avg_p"] for r in rob.rows])))
    assert "offroad_diff" in rob.rows[0] and "collision_diff" in rob.rows[0]  # the synthetic set has maps and boxes
    (reliance,) = rob.reliance
    assert reliance["variant"] == "no-image"
    assert reliance["reliance_pct"] == pytest.approx(100 * rob.rows[1]["ade_avg_diff"] / rob.rows[1]["ade_avg_clean"])
    # evaluating the variant runs alone (no clean run among them): no rows, a warning naming the sweep
    alone = evaluate_runs(
        [out / e["run_dir"] for e in result.manifest["variants"][1:]],
        resampling=Resampling(n_resamples=0),
        safety=False,
        planning=False,
        explanations=False,
    )
    assert alone.robustness.rows == [] and any(
        "its clean run is not among the runs evaluated" in w for w in alone.warnings
    )


def test_evaluate_json_has_the_robustness_section_with_metric_ids_and_the_figure_draws(tmp_path, synth_root, capsys):
    from lightemma.evaluation.descriptors import read_evaluation_json
    from lightemma.evaluation.robustness import robustness_metrics
    from lightemma.report.figures.degradation import robustness_figure

    out = tmp_path / "sweep"
    with FakeOpenAIServer(Driver()) as server:
        code = cli_main(
            [
                "sweep",
                "--model",
                MODEL,
                "--inputs",
                "clean,corrupt:fog@1,corrupt:fog@4,blank-image",
                "--out",
                str(out),
                "--dataroot",
                str(synth_root),
                "--version",
                "v1.0-mini",
                "--sample",
                "4",
                "--api-base",
                server.url,
                "--no-progress",
                "--backoff",
                "0.01",
            ]
        )
    assert code == 0
    printed = capsys.readouterr().out
    assert f"lightemma evaluate {out}" in printed and printed.count("finished") == 4
    target = tmp_path / "ev.json"
    assert (
        cli_main(
            ["evaluate", str(out), "--format", "json", "--resamples", "100", "--no-explanations", "-o", str(target)]
        )
        == 0
    )
    doc = read_evaluation_json(target)  # every column has this version's descriptor
    import jsonschema

    from lightemma.evaluation.descriptors import schema

    jsonschema.validate(doc, schema())  # the robustness section as the published schema says
    names = [t["name"] for t in doc["tables"]]
    assert "robustness" in names and "visual_reliance" in names
    assert doc["robustness"]["metrics"]["ade_avg"] == "ade@lightemma/1"
    assert doc["robustness"]["metrics"]["offroad"] == "offroad@footprint/1"
    assert doc["columns"]["robustness"]["ade_avg_diff"]["id"] == "diff@paired/1"
    assert doc["columns"]["robustness"]["ade_avg_ci95"]["range"] == [None, None]
    rows = doc["robustness"]["rows"]
    assert [(r["corruption"], r["severity"]) for r in rows] == [("fog", 1), ("fog", 4), (None, None)]
    fig = robustness_figure(rows, robustness_metrics("lightemma", None, None))
    assert len(fig.axes) == 1 and len(fig.axes[0].lines) >= 1
    with pytest.raises(ValueError):
        robustness_figure(rows[2:], robustness_metrics("lightemma", None, None))


def test_a_run_refused_before_the_sweeps_first_call_leaves_no_sweep_behind(tmp_path, synth_root):
    with FakeOpenAIServer(Driver()) as server:
        with pytest.raises(UserError) as info:
            run_sweep(server, tmp_path / "sweep", synth_root, reask="bogus")
        assert server.requests == []
    assert "\n" not in str(info.value) and not (tmp_path / "sweep").exists()


def test_the_report_of_a_sweep_has_the_robustness_section_and_the_severity_figure(tmp_path, synth_root):
    out = tmp_path / "sweep"
    with FakeOpenAIServer(Driver()) as server:
        run_sweep(server, out, synth_root, inputs="clean,corrupt:dark@2,corrupt:dark@5,no-image", sample=4)
    report = tmp_path / "report"
    assert cli_main(["report", str(out), "--out", str(report), "--no-pictures", "--resamples", "50"]) == 0
    index = (report / "index.md").read_text()
    assert "## How robust is it?" in index and "figures/robustness.png" in index
    assert (report / "figures" / "robustness.png").stat().st_size > 0
    assert (report / "tables" / "robustness.csv").is_file() and (report / "tables" / "visual_reliance.csv").is_file()
    numbers = json.loads((report / "tables" / "evaluation.json").read_text())
    assert [r["variant"] for r in numbers["robustness"]["rows"]] == ["corrupt:dark@2", "corrupt:dark@5", "no-image"]


def test_an_out_folder_that_holds_other_files_is_not_made_a_sweep(tmp_path, synth_root):
    out = tmp_path / "busy"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    with FakeOpenAIServer(Driver()) as server:
        with pytest.raises(UserError) as info:
            run_sweep(server, out, synth_root)
        assert server.requests == []
    assert "holds files but no sweep.json" in str(info.value) and sorted(p.name for p in out.iterdir()) == ["notes.txt"]
