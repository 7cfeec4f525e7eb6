"""Safety columns in ``lightemma evaluate`` end to end, on synthetic data with known outcomes (docs/definitions.md#safety)."""

import dataclasses
import json
import os
import shutil

import numpy as np
import pytest

from lightemma.cli import main
from lightemma.evaluation import evaluate_loaded, load_run
from lightemma.evaluation import safety as S
from lightemma.evaluation.stats import Resampling
from lightemma.report.evaluation_tables import evaluation_tables
from lightemma.report.tables import ACCURACY_COLUMNS, render
from lightemma.runs.store import find_run_dirs

FAST = Resampling(n_resamples=200, seed=0)


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    from lightemma.synth import write_dataset

    base = tmp_path_factory.mktemp("safety_eval")
    root = write_dataset(base / "data", scenes=8, keyframes=24, image_size=(64, 36), sweeps=False)
    for kind in ("cv", "oracle"):
        assert (
            main(
                [
                    "run",
                    "--model",
                    f"baseline:{kind}",
                    "--dataroot",
                    str(root),
                    "--version",
                    "v1.0-mini",
                    "--split",
                    "all",
                    "--out",
                    str(base / "runs" / kind),
                ]
            )
            == 0
        )
    dirs = {kind: find_run_dirs(base / "runs" / kind)[0] for kind in ("cv", "oracle")}
    return base, root, dirs


def _swerve(run):
    """A perfect run (trajectory = ground truth) but for one frame of the accelerate scene, which swerves
    1.5 m right into the parked car (tests/unit/metrics/test_safety.py computes it by hand); returns the frame index and its
    collision steps."""
    from lightemma.synth import build_scenarios
    from lightemma.synth.maps import scene_agents

    scn = build_scenarios(8, seed=0, keyframes=24)[1]
    parked = scene_agents(scn)[0]
    rows = [i for i, f in enumerate(run.frame_ids) if f.startswith(scn.name + "/")]
    run.trajectory = run.gt_positions.copy()
    data = S.load_safety_data(run.info.dataset["dataroot"], "v1.0-mini")
    for i in rows:
        traj = np.array([[[4.0 * k, -1.5] for k in range(1, 7)]])
        out = S.frame_safety(traj, [S.sample_token_of(run.frame_ids[i])], data)
        if out.collide[0, :, 0].any():
            run.trajectory[i] = traj[0]
            return i, out.collide[0, :, 0].tolist(), parked
    raise AssertionError("no frame of the accelerate scene reaches the parked car")


def test_hand_counted_rates_in_every_table(world):
    base, root, dirs = world
    run = load_run(dirs["oracle"])
    i, steps, _ = _swerve(run)
    n = len(run)
    ev = evaluate_loaded([run], convention="all", resampling=FAST)
    rows = {c: ev.accuracy_rows(c)[0] for c in ("lightemma", "stp3", "uniad")}
    # off-road: only the swerving frame (its corners leave the lane from step 1, its reference point never does)
    for r in rows.values():
        assert (
            r["offroad"] == pytest.approx(1 / n)
            and r["offroad_1s"] == pytest.approx(1 / n)
            and r["offroad_centre"] == 0.0
        )
        assert (
            r["safety_frames"] == r["offroad_frames"] == r["collision_frames"] == n and r["area_source"] == "expansion"
        )
        assert r["collision_vru"] == 0.0
    c = np.array(steps, dtype=float)
    any_t = [c[: 2 * s].max() / n for s in (1, 2, 3)]
    stp3_t = [c[: 2 * s].mean() / n for s in (1, 2, 3)]
    uniad_t = [c[2 * s - 1] / n for s in (1, 2, 3)]
    assert [rows["lightemma"][f"collision_{s}s"] for s in (1, 2, 3)] == pytest.approx(any_t)
    assert rows["lightemma"]["collision"] == pytest.approx(1 / n) and rows["lightemma"]["collision_convention"] == "any"
    assert [rows["stp3"][f"collision_{s}s"] for s in (1, 2, 3)] == pytest.approx(stp3_t)
    assert rows["stp3"]["collision"] == pytest.approx(np.mean(stp3_t))
    assert [rows["uniad"][f"collision_{s}s"] for s in (1, 2, 3)] == pytest.approx(uniad_t)
    assert rows["uniad"]["collision_vehicle"] == pytest.approx(np.mean(uniad_t))
    floor = ev.safety.floor["lightemma"]
    assert floor["offroad"] == 0.0 and floor["collision"] == 0.0 and floor["model"] == S.FLOOR_LABEL
    assert ev.safety.gt_off_scenes == [] and rows["lightemma"]["offroad_ci95"] is not None
    tables = evaluation_tables(ev)
    md = render(tables, "md")
    assert "Off-road (%) [95% CI]" in md and "Collision (%) [95% CI]" in md and "| Ground truth (floor) |" in md
    assert f"| {100 / n:.2f} [" in md  # off-road of the lightemma table with its interval
    csv = render(tables, "csv")
    assert "Off-road (%),Off-road (%) CI low,Off-road (%) CI high" in csv and "Collision (%) CI low" in csv
    assert "Off-road (\\%) [95\\% CI]" in render(tables, "latex")
    doc = json.loads(render(tables, "json"))
    acc = next(t for t in doc["tables"] if t["name"] == "accuracy_lightemma")
    assert acc["rows"][0]["collision"] == pytest.approx(1 / n) and acc["rows"][-1]["model"] == S.FLOOR_LABEL


def test_na_without_dataroot_and_without_annotations(world, tmp_path):
    base, root, dirs = world
    run = load_run(dirs["cv"])
    run.info = dataclasses.replace(run.info, dataset={})
    ev = evaluate_loaded([run], resampling=FAST)
    row = ev.accuracy_rows("lightemma")[0]
    assert row["offroad"] is None and row["collision"] is None
    md = render(evaluation_tables(ev), "md")
    assert "n/a (no dataroot (pass --dataroot and --version))" in md
    # a version without annotations (as v1.0-test): off-road numbers, collision n/a (no annotations), never 0
    copy = tmp_path / "test-like"
    shutil.copytree(root, copy)
    (copy / "v1.0-mini" / "sample_annotation.json").write_text("[]")
    ev = evaluate_loaded([run], resampling=FAST, dataroot=copy, version="v1.0-mini")
    row = ev.accuracy_rows("lightemma")[0]
    assert row["offroad"] is not None and row["collision"] is None and row["collision_na"] == "no annotations"
    md = render(evaluation_tables(ev), "md")
    assert "n/a (no annotations)" in md and "| Ground truth (floor) |" in md


def test_a_given_dataroot_that_is_not_there_is_an_error_and_a_gone_recorded_one_is_named(world, tmp_path, capsys):
    base, root, dirs = world
    (tmp_path / "afile").write_text("x")
    for dataroot, version, message in (
        (tmp_path / "nonexistent", "v1.0-mini", f"--dataroot {tmp_path / 'nonexistent'} does not exist"),
        (tmp_path / "afile", "v1.0-mini", f"--dataroot {tmp_path / 'afile'} is not a folder"),
        (root, "v9", f"--version v9: --dataroot {root} has no folder v9"),
    ):
        assert (
            main(["evaluate", str(dirs["cv"]), "--dataroot", str(dataroot), "--version", version, "--resamples", "0"])
            == 2
        )
        captured = capsys.readouterr()
        assert captured.err == f"lightemma evaluate: error: {message}\n" and captured.out == ""
    # the run's recorded dataroot (or its version folder) is gone: the n/a says so, not "no dataroot"
    run = load_run(dirs["cv"])
    gone = tmp_path / "moved-away"
    for dataset, named in (
        ({"dataroot": str(gone), "version": "v1.0-mini"}, str(gone)),
        ({"dataroot": str(root), "version": "v9"}, str(root / "v9")),
    ):
        run.info = dataclasses.replace(run.info, dataset=dataset)
        ev = evaluate_loaded([run], resampling=FAST)
        row = ev.accuracy_rows("lightemma")[0]
        reason = f"recorded dataroot {named} is gone; pass --dataroot"
        assert (
            row["offroad"] is None and row["collision"] is None and row["offroad_na"] == row["collision_na"] == reason
        )
        assert f"n/a ({reason})" in render(evaluation_tables(ev), "md")


def test_cli_dataroot_with_paper_and_pairwise(world, capsys):
    base, root, dirs = world
    assert main(["evaluate", str(dirs["cv"]), "--dataroot", str(root)]) == 2
    assert "--dataroot needs --version" in capsys.readouterr().err
    assert (
        main(["evaluate", str(base / "runs"), "--with-paper", "--resamples", "100", "--pairwise", "--format", "json"])
        == 0
    )
    doc = json.loads(capsys.readouterr().out)
    names = [t["name"] for t in doc["tables"]]
    assert "safety_lightemma" in names and "pairwise_safety" in names
    acc = next(t for t in doc["tables"] if t["name"] == "accuracy_lightemma")
    assert not any("offroad" in r for r in acc["rows"] if r.get("source") == "paper")
    # the paper's table keeps its columns
    assert main(["evaluate", str(base / "runs"), "--with-paper", "--resamples", "0"]) == 0
    md = capsys.readouterr().out
    block = md.split("### Accuracy — lightemma")[1].split("###")[0]
    assert block.splitlines()[2] == "| " + " | ".join(c.header for c in ACCURACY_COLUMNS) + " |"
    # paired: cv − oracle on the frames both have, as the difference of their per-frame values
    pair = next(t for t in doc["tables"] if t["name"] == "pairwise_safety")["rows"]
    ev = evaluate_loaded([load_run(d) for d in dirs.values()], resampling=FAST, pairwise=True)
    rows = {r["model"]: r for r in ev.accuracy_rows("lightemma")}
    off = next(r for r in pair if r["metric"] == "offroad")
    a, b = off["model_a"], off["model_b"]
    assert off["diff"] == pytest.approx(rows[a]["offroad"] - rows[b]["offroad"]) and off["frames"] == rows[a]["frames"]
    assert main(["evaluate", str(base / "runs"), "--no-safety", "--resamples", "0"]) == 0
    assert "Off-road" not in capsys.readouterr().out


def test_imported_runs_get_safety_numbers_with_a_dataroot(world, tmp_path, capsys):
    from lightemma import load_frames
    from lightemma.runs.importer import import_reference
    from tests.support.reference_fixtures import euler, make_frame, strict_answer, write_scene

    base, root, dirs = world
    fs = load_frames(root, "v1.0-mini", split="all")
    rng = np.random.default_rng(3)
    by_scene: dict[str, list] = {}
    trajectories = []
    for i in range(len(fs)):
        name = fs.scene_names[i]
        j = len(by_scene.setdefault(name, []))
        frame = make_frame(rng, name, j)
        frame["sample_token"] = fs.sample_tokens[i]
        frame["ego_info"]["position"] = fs.ego_poses[i, :2].tolist()
        frame["ego_info"]["heading"] = float(fs.ego_poses[i, 2])
        frame["ego_info"]["gt_positions"] = fs.gt_positions[i].tolist()
        actions = np.round(fs.gt_actions[i], 3).tolist()
        frame["inference"]["pred_actions_str"] = strict_answer(actions)
        frame["predictions"] = {"pred_actions": actions, "trajectory": euler(actions)}
        trajectories.append(euler(actions))
        by_scene[name].append(frame)
    first = next(iter(by_scene.values()))[0]
    first["ego_info"]["position"] = [first["ego_info"]["position"][0] + 50.0, first["ego_info"]["position"][1]]
    for name, frames in by_scene.items():
        write_scene(tmp_path / "results" / "gpt-4o", name, frames)
    (run,) = import_reference([tmp_path / "results" / "gpt-4o"], tmp_path / "runs", dataset_kind="synthetic")
    assert main(["evaluate", str(run.run_dir), "--resamples", "0", "--format", "json"]) == 0
    row = json.loads(capsys.readouterr().out)["tables"][1]["rows"][0]
    assert row["offroad"] is None and row["offroad_na"].startswith("no dataroot")
    assert (
        main(
            [
                "evaluate",
                str(run.run_dir),
                "--resamples",
                "0",
                "--format",
                "json",
                "--dataroot",
                str(root),
                "--version",
                "v1.0-mini",
            ]
        )
        == 0
    )
    doc = json.loads(capsys.readouterr().out)
    row = doc["tables"][1]["rows"][0]
    # one frame's recorded position was moved 50 m: it is not placed, and a warning says why
    assert row["offroad_frames"] == row["collision_frames"] == row["frames"] - 1 == len(fs) - 1
    assert any("50.0 m from v1.0-mini's pose" in w for w in doc["warnings"])
    keep = np.ones(len(fs), dtype=bool)
    keep[[i for i in range(len(fs)) if fs.sample_tokens[i] == first["sample_token"]]] = False
    # the imported trajectories placed with the dataroot's poses
    tokens = [t for t, k in zip(fs.sample_tokens, keep) if k]
    want = S.rates(
        S.safety_values(
            S.frame_safety(np.array(trajectories)[keep], tokens, S.load_safety_data(root, "v1.0-mini")), "any"
        )
    )
    assert row["offroad"] == pytest.approx(want["offroad"]) and row["collision"] == pytest.approx(want["collision"])
    assert 0.0 < row["offroad"] < 0.5


def test_bird_eye_view_marks_the_colliding_steps(world):
    from matplotlib.colors import to_hex

    from lightemma.report.figures.bev import COLLISION_COLOR, bev_figure

    base, root, dirs = world
    run = load_run(dirs["oracle"])
    i, steps, _ = _swerve(run)
    data = S.load_safety_data(root, "v1.0-mini")
    fig = bev_figure(run.frame_ids[i], [("swerve", run.trajectory[i], "#1f77b4")], run.gt_positions[i], data)
    patches = fig.axes[0].patches
    filled = [p for p in patches if p.get_fill() and to_hex(p.get_facecolor()) == COLLISION_COLOR]
    dashed = [p for p in patches if p.get_linestyle() == "--"]
    assert len(filled) == sum(steps) and len(dashed) == 6  # every step of the swerve has a corner off the road
    agents = sum(len(data.boxes[t]) for t in data.future[S.sample_token_of(run.frame_ids[i])])
    assert agents > 0 and len([p for p in patches if not p.get_fill()]) >= agents + 12 - sum(steps)


def test_report_has_safety_tags_and_views(world, tmp_path):
    from lightemma.evaluation.scenarios import per_tag_metrics
    from lightemma.report import write_report

    base, root, dirs = world
    index = write_report(
        [base / "runs"],
        tmp_path / "rep",
        convention="lightemma",
        top=0,
        case_tags=(),
        resampling=Resampling(n_resamples=0),
    )
    text = index.read_text()
    assert "## Safety — bird's-eye views" in text and list((tmp_path / "rep" / "figures").glob("bev_*.png"))
    runs = [load_run(d, details=True) for d in dirs.values()]
    ev = evaluate_loaded(runs, resampling=Resampling(n_resamples=0))
    order = {m.run_dir: k for k, m in enumerate(ev.models)}
    runs.sort(key=lambda r: order[r.info.run_dir])
    tags = {r["tag"]: r for r in per_tag_metrics(runs, safety=ev.safety)}
    for m in ev.models:
        rs = ev.safety.runs[m.label]
        assert tags["off_road"][f"{m.label} frames"] == int((rs.model.off_steps.any(axis=1)).sum())
        assert tags["collides"][f"{m.label} frames"] == int(rs.model.collide.any(axis=(1, 2)).sum())
    assert "| off_road |" in text and "| collides |" in text


def test_a_map_mask_named_outside_the_dataroot_is_never_read(tmp_path):
    """The map table's filename must lie inside the dataroot, as every dataset file name must (lightemma.nuscenes.dataset_path):
    one that climbs out gives the frames n/a with the reason, even where a readable mask lies there."""
    import shutil

    from lightemma.evaluation.safety import load_safety_data
    from lightemma.synth import write_dataset

    root = write_dataset(tmp_path / "data", scenes=1, keyframes=20, image_size=(64, 36), sweeps=False)
    shutil.rmtree(root / "maps" / "expansion", ignore_errors=True)  # the base mask is what is read then
    table = root / "v1.0-mini" / "map.json"
    maps = json.loads(table.read_text())
    inside = root / maps[0]["filename"]
    shutil.copy(inside, tmp_path / "outside.png")  # a real, readable mask outside the dataroot
    from lightemma.evaluation.safety import DrivableArea

    assert all(
        isinstance(a, DrivableArea) for a in load_safety_data(root, "v1.0-mini").areas.values()
    )  # the mask, read
    for name in ("../outside.png", str(tmp_path / "outside.png")):
        maps[0]["filename"] = name
        table.write_text(json.dumps(maps))
        (reason,) = set(load_safety_data(root, "v1.0-mini").areas.values())
        assert isinstance(reason, str) and ("leaves the dataroot" in reason or "absolute path" in reason), reason


def test_a_log_location_that_is_a_path_never_reads_a_map_outside_the_dataroot(tmp_path):
    """log.location names the map expansion file: "../../../x" would read tmp_path/x.json as the drivable area."""
    import shutil

    from lightemma.evaluation.safety import load_safety_data
    from lightemma.synth import write_dataset

    root = write_dataset(tmp_path / "data", scenes=1, keyframes=20, image_size=(64, 36), sweeps=False)
    logs = json.loads((root / "v1.0-mini" / "log.json").read_text())
    (expansion,) = list((root / "maps" / "expansion").glob("*.json"))
    shutil.copy(expansion, tmp_path / "outside_exp.json")  # a readable expansion outside the dataroot
    outside = os.path.relpath(tmp_path / "outside_exp", root / "maps" / "expansion")
    assert outside.startswith("..")
    for log in logs:
        log["location"] = outside
    (root / "v1.0-mini" / "log.json").write_text(json.dumps(logs))
    (reason,) = set(load_safety_data(root, "v1.0-mini").areas.values())
    assert isinstance(reason, str) and "is not a map name" in reason, reason
