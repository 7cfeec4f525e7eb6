"""The planning score in ``lightemma evaluate`` and ``lightemma report`` end to end, on synthetic data
(lightemma.evaluation.planning_score; docs/definitions.md#planning-score)."""

import json
import shutil

import numpy as np
import pytest

from lightemma.cli import main
from lightemma.evaluation import evaluate_loaded, load_run
from lightemma.evaluation import planning_score as P
from lightemma.evaluation.stats import Resampling
from lightemma.runs.store import find_run_dirs

FAST = Resampling(n_resamples=100, seed=0)
VERSION = "v1.0-mini"


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    from lightemma.synth import write_dataset

    base = tmp_path_factory.mktemp("planning_eval")
    # 8 scenes: the turning ones give the map its intersections
    root = write_dataset(base / "data", scenes=8, keyframes=22, image_size=(64, 36), sweeps=False)
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
                    VERSION,
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


def _planning_table(doc):
    return next(t for t in doc["tables"] if t["name"] == "planning")


def _copy(root, tmp_path):
    dest = tmp_path / "data"
    shutil.copytree(root, dest, ignore=shutil.ignore_patterns("samples", "sweeps"))
    return dest


def _edit_table(root, name, edit):
    path = root / VERSION / f"{name}.json"
    rows = json.loads(path.read_text())
    edit(rows)
    path.write_text(json.dumps(rows))


def test_json_has_every_key_in_range_and_the_ground_truth_row(world, capsys):
    base, root, dirs = world
    assert main(["evaluate", str(base / "runs"), "--format", "json", "--resamples", "100"]) == 0
    doc = json.loads(capsys.readouterr().out)
    rows = _planning_table(doc)["rows"]
    labels = [r["model"] for r in rows]
    assert labels[-1] == P.GT_LABEL and len(rows) == 3
    for row in rows:
        for key in P.KEYS:
            assert key in row and f"{key}_ci95" in row and f"{key}_na" in row
            value = row[key]
            assert value is None or 0.0 <= value <= 1.0
            assert (value is None) == (row[f"{key}_na"] is not None), (row["model"], key)
            if row[f"{key}_ci95"] is not None:
                low, high = row[f"{key}_ci95"]
                assert 0.0 <= low <= value <= high <= 1.0
        assert row["tlc"] is None and "traffic-light" in row["tlc_na"]
        assert row["planning_frames"] > 0
    oracle = next(r for r in rows if "oracle" in r["model"])
    gt = rows[-1]
    assert oracle["nc"] == gt["nc"] == 1.0 and 0.9 <= gt["dac"] <= 1.0
    # annotations are there: epdms is the score and epdms_map says so
    assert gt["epdms_map"] is None and "the score is epdms" in gt["epdms_map_na"]
    assert gt["planning_frames"] == oracle["planning_frames"]
    # the synthetic map has lanes and intersections: every aggregate of the ground truth and the oracle is scored, the
    # ground truth the best (NAVSIM's human agent: about 0.94 PDMS on navtest)
    cv = next(r for r in rows if "velocity" in r["model"])
    for key in ("pdms", "epdms", "ddc", "lk", "ep"):
        assert gt[key] is not None and oracle[key] is not None, key
    assert gt["epdms"] >= oracle["epdms"] > cv["epdms"]


def test_pairwise_covers_the_headline_aggregate(world, capsys):
    base, root, dirs = world
    assert main(["evaluate", str(base / "runs"), "--format", "json", "--resamples", "100", "--pairwise"]) == 0
    doc = json.loads(capsys.readouterr().out)
    rows = {r["model"]: r for r in _planning_table(doc)["rows"]}
    (pair,) = next(t for t in doc["tables"] if t["name"] == "pairwise_planning")["rows"]
    assert pair["metric"] == "epdms" and pair["frames"] > 0 and pair["p_holm"] is not None
    assert set(rows) >= {pair["model_a"], pair["model_b"]}
    # the mean paired difference on the frames where both have a value, from the per-frame values
    ev = evaluate_loaded([load_run(d, details=True) for d in dirs.values()], resampling=Resampling(n_resamples=0))
    va, vb = (
        dict(zip(ev.planning.runs[m].frame_ids, ev.planning.runs[m].values["epdms"]))
        for m in (pair["model_a"], pair["model_b"])
    )
    both = [f for f in va if f in vb and np.isfinite(va[f]) and np.isfinite(vb[f])]
    assert pair["frames"] == len(both)
    assert pair["diff"] == pytest.approx(float(np.mean([va[f] - vb[f] for f in both])))


def test_the_ground_truth_and_the_oracle_stay_on_the_road_without_turns(world):
    """Re-simulated, the ground truth keeps to the road and hits nothing. The synthetic turns begin with a step in
    curvature at a keyframe that nuPlan's LQR tracker (steering lag, lateral weight 1) follows late, so their footprint
    cuts the inner edge: the turning scenes are left out of the dac check (tests/unit/planning/test_planning_simulation.py checks the
    tracker itself)."""
    base, root, dirs = world
    run = load_run(dirs["oracle"], details=True)
    ev = evaluate_loaded([run], resampling=Resampling(n_resamples=0))
    for label in (ev.models[0].label, P.GT_LABEL):
        rp = ev.planning.runs[label]
        assert np.all(rp.values["nc"] == 1.0)
        straight = np.array(["turn" not in f.split("/")[0] for f in rp.frame_ids])
        assert straight.sum() >= 40 and np.all(rp.values["dac"][straight] == 1.0), label


def test_markdown_table_and_no_planning_switch(world, capsys):
    base, root, dirs = world
    assert main(["evaluate", str(base / "runs"), "--resamples", "0"]) == 0
    md = capsys.readouterr().out
    block = md.split("### Planning score (NAVSIM)")[1].split("###")[0]
    assert f"| {P.GT_LABEL} |" in block
    assert "| NC | DAC | DDC | TLC | EP | TTC | LK | C | HC | EC | Drivable area |" in block
    assert "n/a (nuScenes has no traffic-light states" in block
    assert main(["evaluate", str(base / "runs"), "--resamples", "0", "--no-planning"]) == 0
    assert "Planning score" not in capsys.readouterr().out


def test_missing_layers_are_na_with_the_reason(world, tmp_path, capsys):
    base, root, dirs = world
    data = _copy(root, tmp_path)
    for path in (data / "maps" / "expansion").glob("*.json"):
        doc = json.loads(path.read_text())
        for layer in ("lane", "lane_connector", "road_segment"):
            doc[layer] = []
        path.write_text(json.dumps(doc))
    assert (
        main(
            [
                "evaluate",
                str(dirs["oracle"]),
                "--dataroot",
                str(data),
                "--version",
                VERSION,
                "--format",
                "json",
                "--resamples",
                "0",
            ]
        )
        == 0
    )
    doc = json.loads(capsys.readouterr().out)
    row = _planning_table(doc)["rows"][0]
    assert row["ddc"] is None and "no lane polygons" in row["ddc_na"]
    assert row["lk"] is None and "intersection" in row["lk_na"]
    assert row["epdms"] is None and "ddc" in row["epdms_na"]
    assert row["dac"] is not None and row["planning_map"] == "expansion"
    assert any("planning score" in w and "no lane polygons" in w for w in doc["warnings"])
    # no expansion at all: the drivable area is the base map mask, still scored
    shutil.rmtree(data / "maps" / "expansion")
    assert (
        main(
            [
                "evaluate",
                str(dirs["oracle"]),
                "--dataroot",
                str(data),
                "--version",
                VERSION,
                "--format",
                "json",
                "--resamples",
                "0",
            ]
        )
        == 0
    )
    row = _planning_table(json.loads(capsys.readouterr().out))["rows"][0]
    assert row["planning_map"] == "mask" and row["dac"] is not None and row["ddc"] is None


def test_a_plan_with_nan_is_na_and_counted_in_the_warnings(world):
    base, root, dirs = world
    run = load_run(dirs["cv"], details=True)
    row = int(np.flatnonzero(run.valid)[3])
    run.actions[row, 2, 0] = np.nan  # the trajectory stays finite: the frame is still scored for ADE
    ev = evaluate_loaded([run], resampling=FAST)
    rp = ev.planning.runs[ev.models[0].label]
    j = rp.frame_ids.index(run.frame_ids[row])
    for key in ("pdms", "nc", "dac", "c", "hc"):
        assert np.isnan(rp.values[key][j]) and "NaN" in rp.reasons[key][j]
    others = np.delete(rp.values["dac"], j)
    assert np.isfinite(others).all()
    assert any("planning score: 1 frame(s)" in w and "actions hold a NaN" in w for w in ev.warnings)


def test_a_trajectory_that_is_not_its_actions_is_na(world):
    base, root, dirs = world
    run = load_run(dirs["oracle"], details=True)
    row = int(np.flatnonzero(run.valid)[0])
    run.trajectory[row] += 0.5  # two readings of the plan disagree
    ev = evaluate_loaded([run], resampling=Resampling(n_resamples=0))
    rp = ev.planning.runs[ev.models[0].label]
    j = rp.frame_ids.index(run.frame_ids[row])
    assert np.isnan(rp.values["dac"][j]) and "disagree" in rp.reasons["dac"][j]


def test_a_frame_without_a_pose_and_a_degenerate_box_are_na(world, tmp_path):
    base, root, dirs = world
    data = _copy(root, tmp_path)
    run = load_run(dirs["oracle"])
    rows = np.flatnonzero(run.valid)
    no_pose = run.frame_ids[rows[5]].rsplit("/", 1)[-1]
    boxed = run.frame_ids[rows[12]].rsplit("/", 1)[-1]
    front = {
        c["token"]
        for c in json.loads((data / VERSION / "calibrated_sensor.json").read_text())
        if c["sensor_token"]
        in {s["token"] for s in json.loads((data / VERSION / "sensor.json").read_text()) if s["channel"] == "CAM_FRONT"}
    }
    sd = json.loads((data / VERSION / "sample_data.json").read_text())
    pose_token = next(
        r["ego_pose_token"]
        for r in sd
        if r["sample_token"] == no_pose and r["is_key_frame"] and r["calibrated_sensor_token"] in front
    )
    _edit_table(data, "ego_pose", lambda rs: rs.remove(next(r for r in rs if r["token"] == pose_token)))

    def shrink(rs):
        ann = next(r for r in rs if r["sample_token"] == boxed)
        ann["size"] = [0.0, 0.0, 0.0]

    _edit_table(data, "sample_annotation", shrink)
    ev = evaluate_loaded([run], resampling=Resampling(n_resamples=0), dataroot=data, version=VERSION)
    rp = ev.planning.runs[ev.models[0].label]
    j = rp.frame_ids.index(run.frame_ids[rows[5]])
    assert np.isnan(rp.values["dac"][j]) and "no CAM_FRONT ego pose" in rp.reasons["dac"][j]
    k = rp.frame_ids.index(run.frame_ids[rows[12]])
    assert np.isnan(rp.values["nc"][k]) and "refused annotation" in rp.reasons["nc"][k]
    assert np.isfinite(rp.values["dac"][k])  # only the agent-based sub-scores are n/a
    assert any("no CAM_FRONT ego pose" in w for w in ev.warnings)
    assert any("refused annotation" in w and "planning score" in w for w in ev.warnings)


def test_no_dataset_is_na_for_every_key_never_a_traceback(world, tmp_path):
    base, root, dirs = world
    run = load_run(dirs["cv"])
    (tmp_path / VERSION).mkdir()
    ev = evaluate_loaded([run], resampling=FAST, dataroot=tmp_path, version=VERSION, safety=False)
    row = ev.models[0].planning
    assert all(row[k] is None and "sensor.json is missing" in row[f"{k}_na"] for k in P.KEYS)
    assert any(w.startswith("planning score:") for w in ev.warnings)


def test_pairwise_on_the_headline_aggregate_by_hand():
    ids = [f"s{i // 3}/t{i}" for i in range(9)]
    a = np.array([1.0, 0.5, 0.8, 0.9, 0.7, np.nan, 1.0, 0.2, 0.6])
    b = np.array([0.5, 0.5, 0.9, 0.4, 0.7, 0.3, 0.8, np.nan, 0.1])
    runs = {
        label: P.RunPlanning(ids, np.arange(9), {"epdms": v}, {"epdms": [None] * 9})
        for label, v in (("A", a), ("B", b))
    }
    result = P.PlanningResult(rows={}, ground_truth=None, runs=runs, headline="epdms")
    (row,) = P.pairwise_planning(result, ["A", "B"], FAST)
    both = np.isfinite(a) & np.isfinite(b)
    assert row["frames"] == 7 and row["metric"] == "epdms"
    assert row["diff"] == pytest.approx(float((a - b)[both].mean()))
    assert row["ci95"][0] <= row["diff"] <= row["ci95"][1] and 0 < row["p_value"] <= 1


def test_scenario_tags_from_the_sub_scores():
    ids = ["s/a", "s/b", "s/c", "s/d"]
    values = {
        "ddc": np.array([1.0, 0.5, np.nan, 0.0]),
        "c": np.array([1.0, 0.0, np.nan, 1.0]),
        "ep": np.array([0.0, 0.4, np.nan, 1.0]),
    }
    tags = P.frame_tags(P.RunPlanning(ids, np.arange(4), values, {}))
    assert tags["wrong-way"].tolist() == [False, True, False, True]
    assert tags["uncomfortable"].tolist() == [False, True, False, False]
    assert tags["no-progress"].tolist() == [True, False, False, False]


def test_report_has_the_table_the_figure_and_the_tags(world, tmp_path):
    base, root, dirs = world
    out = tmp_path / "report"
    assert (
        main(
            [
                "report",
                str(base / "runs"),
                "--out",
                str(out),
                "--no-pictures",
                "--resamples",
                "50",
                "--convention",
                "lightemma",
            ]
        )
        == 0
    )
    index = (out / "index.md").read_text()
    assert "### Planning score (NAVSIM)" in index and P.GT_LABEL in index
    assert (out / "figures" / "planning.png").is_file()
    for tag in P.PLANNING_TAGS:
        assert f"| {tag} |" in index
    doc = json.loads((out / "tables" / "evaluation.json").read_text())
    assert doc["planning"]["ground_truth"]["model"] == P.GT_LABEL


def test_imported_runs_get_the_score_with_a_dataroot(world, tmp_path, capsys):
    from lightemma import load_frames
    from lightemma.runs.importer import import_reference
    from tests.support.reference_fixtures import euler, make_frame, strict_answer, write_scene

    base, root, dirs = world
    fs = load_frames(root, VERSION, split="all")
    rng = np.random.default_rng(3)
    by_scene: dict[str, list] = {}
    for i in range(len(fs)):
        name = fs.scene_names[i]
        frame = make_frame(rng, name, len(by_scene.setdefault(name, [])))
        frame["sample_token"] = fs.sample_tokens[i]
        frame["ego_info"]["position"] = fs.ego_poses[i, :2].tolist()
        frame["ego_info"]["heading"] = float(fs.ego_poses[i, 2])
        frame["ego_info"]["gt_positions"] = fs.gt_positions[i].tolist()
        actions = np.round(fs.gt_actions[i], 3).tolist()
        frame["inference"]["pred_actions_str"] = strict_answer(actions)
        frame["predictions"] = {"pred_actions": actions, "trajectory": euler(actions)}
        by_scene[name].append(frame)
    moved = next(iter(by_scene.values()))[3]
    moved["ego_info"]["position"] = [moved["ego_info"]["position"][0] + 50.0, moved["ego_info"]["position"][1]]
    for name, frames in by_scene.items():
        write_scene(tmp_path / "results" / "gpt-4o", name, frames)
    (run,) = import_reference([tmp_path / "results" / "gpt-4o"], tmp_path / "runs", dataset_kind="synthetic")
    assert main(["evaluate", str(run.run_dir), "--resamples", "0", "--format", "json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert "planning" not in [t["name"] for t in doc["tables"]]  # no dataroot: no numbers to show
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
                VERSION,
            ]
        )
        == 0
    )
    doc = json.loads(capsys.readouterr().out)
    row = _planning_table(doc)["rows"][0]
    assert row["nc"] == 1.0 and 0.8 < row["dac"] <= 1.0 and row["c"] is not None and row["epdms"] is not None
    # the frame whose recorded position is 50 m from the dataroot's pose is n/a, and said
    assert any("planning score: 1 frame(s)" in w and "50.0 m from" in w for w in doc["warnings"])


def test_the_frame_browser_carries_the_simulated_path(world, tmp_path):
    base, root, dirs = world
    out = tmp_path / "report"
    assert (
        main(
            [
                "report",
                str(dirs["oracle"]),
                "--out",
                str(out),
                "--no-pictures",
                "--resamples",
                "0",
                "--convention",
                "lightemma",
            ]
        )
        == 0
    )
    text = (out / "html" / "data.js").read_text()
    data = json.loads(text[text.index("(") + 1 : text.rindex(")")])
    sim = np.array([np.nan if v is None else v for v in data["sim"][0]]).reshape(len(data["ids"]), 11, 2)
    pred = np.array([np.nan if v is None else v for v in data["pred"][0]]).reshape(len(data["ids"]), 6, 2)
    shown = np.isfinite(sim).all(axis=(1, 2))
    assert shown.sum() >= 40
    assert np.allclose(sim[shown, 0], 0.0)  # from the ego now
    # 3 s: the simulated plan ends near the plan itself (the tracker follows it within metres)
    gap = np.linalg.norm(sim[shown, -1] - pred[shown, -1], axis=1)
    assert np.median(gap) < 0.5 and gap.max() < 3.0
    page = (out / "index.html").read_text() + "".join(p.read_text() for p in out.rglob("*.js"))
    assert "D.sim" in page  # the frame view's script draws it


def test_can_bus_that_disagrees_or_cannot_be_read_gives_no_initial_state(world, tmp_path):
    base, root, dirs = world
    data = _copy(root, tmp_path)
    files = sorted((data / "can_bus").glob("*_pose.json"))
    assert len(files) == 8  # lightemma synth writes the CAN bus expansion
    fast, broken = files[0], files[1]
    messages = json.loads(fast.read_text())
    for msg in messages:
        msg["vel"][0] += 10.0  # 10 m/s faster than the poses move
    fast.write_text(json.dumps(messages))
    broken.write_text("{not json")
    run = load_run(dirs["oracle"], details=True)
    ev = evaluate_loaded([run], resampling=Resampling(n_resamples=0), dataroot=data, version=VERSION)
    rp = ev.planning.runs[ev.models[0].label]
    scene = np.array([f.split("/")[0] for f in rp.frame_ids])
    for path, words in ((fast, "disagree"), (broken, "CAN bus")):
        rows = np.flatnonzero(scene == path.name.removesuffix("_pose.json"))
        assert len(rows) and np.isnan(rp.values["pdms"][rows]).all() and np.isnan(rp.values["dac"][rows]).all()
        assert all(words in rp.reasons["dac"][i] for i in rows)
    others = np.flatnonzero(~np.isin(scene, [f.name.removesuffix("_pose.json") for f in (fast, broken)]))
    assert np.isfinite(rp.values["dac"][others]).all()
    assert any("planning score" in w and "disagree" in w for w in ev.warnings)


def test_too_little_history_gives_no_initial_state_or_no_history_comfort(world):
    from lightemma.evaluation import safety as S

    base, root, dirs = world
    run = load_run(dirs["oracle"])
    tok = run.frame_ids[0].rsplit("/", 1)[-1]
    data = S.load_safety_data(root, VERSION, samples={tok}, history=P.HISTORY_KEYFRAMES)
    assert len(data.past[tok]) == P.HISTORY_KEYFRAMES
    scene = run.frame_ids[0].split("/")[0]
    full = P._frames(data, [tok], [scene])
    assert full.reason == [None] and full.past_reason == [None] and np.isfinite(full.init).all()
    data.past[tok] = data.past[tok][:3]  # 1.0 s of past: an initial state, no history comfort
    three = P._frames(data, [tok], [scene])
    assert three.reason == [None] and "history comfort needs 4" in three.past_reason[0]
    assert np.isnan(three.past).all()
    data.past[tok] = data.past[tok][:1]  # a scene's second keyframe: no initial state
    one = P._frames(data, [tok], [scene])
    assert "the initial ego state needs 2" in one.reason[0] and np.isnan(one.init).all()


def test_a_cone_in_the_path_is_a_static_object_at_fault_half(world, tmp_path):
    """NAVSIM counts every tracked object outside nuPlan's AGENT_TYPES as a static object: always "stopped", so
    the ego that meets one is at fault, and the at-fault score is 0.5 (``pdm_scorer.py`` l. 407–414, commit 0a380a9;
    ``pdm_scorer_utils.get_collision_type``). A traffic cone annotated (movable_object.trafficcone, all keyframes of
    its scene, one instance) on the ground truth's path 1.5 s after a cruise keyframe: that frame's ground truth and
    the oracle (which drives the ground truth) get nc 0.5; a cone seen at one keyframe only is no degenerate box (a
    static object has no velocity); the safety metrics never see either."""
    from lightemma.evaluation.safety import load_safety_data
    from lightemma.synth.dataset import quaternion_from_yaw

    base, root, dirs = world
    data = _copy(root, tmp_path)
    run = load_run(dirs["oracle"])
    rows = [r for r in np.flatnonzero(run.valid) if "cruise" in run.frame_ids[r]]
    frame = run.frame_ids[rows[6]]
    tok = frame.rsplit("/", 1)[-1]
    samples = {s["token"]: s for s in json.loads((data / VERSION / "sample.json").read_text())}
    chain, nxt = [], tok
    for _ in range(4):  # the keyframe and the next three
        chain.append(nxt)
        nxt = samples[nxt]["next"]
    scene = [t for t, s in samples.items() if s["scene_token"] == samples[tok]["scene_token"]]
    lone = scene[0] if scene[0] not in chain else scene[-1]
    sd = json.loads((data / VERSION / "sample_data.json").read_text())
    poses = {p["token"]: p for p in json.loads((data / VERSION / "ego_pose.json").read_text())}
    pose = next(poses[r["ego_pose_token"]] for r in sd if r["sample_token"] == chain[3] and r["is_key_frame"])
    w, x, y, z = pose["rotation"]
    yaw = float(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))
    at = [pose["translation"][0] + 1.444 * np.cos(yaw), pose["translation"][1] + 1.444 * np.sin(yaw)]
    cat = "cone-category"

    def add_category(rs):
        rs.append({"token": cat, "name": "movable_object.trafficcone", "description": "cone"})

    def add_instances(rs):
        rs.append({"token": "cone", "category_token": cat, "nbr_annotations": len(scene)})
        rs.append({"token": "lone-cone", "category_token": cat, "nbr_annotations": 1})

    def add_annotations(rs):
        for i, s in enumerate(scene + [lone]):
            rs.append(
                {
                    "token": f"cone-{i}",
                    "sample_token": s,
                    "instance_token": "cone" if i < len(scene) else "lone-cone",
                    "visibility_token": "4",
                    "attribute_tokens": [],
                    "translation": [at[0] if i < len(scene) else at[0] + 500.0, at[1], 0.4],
                    "size": [0.4, 0.4, 0.8],
                    "rotation": quaternion_from_yaw(0.0),
                    "prev": "",
                    "next": "",
                    "num_lidar_pts": 5,
                    "num_radar_pts": 0,
                }
            )

    _edit_table(data, "category", add_category)
    _edit_table(data, "instance", add_instances)
    _edit_table(data, "sample_annotation", add_annotations)
    before = evaluate_loaded([run], resampling=Resampling(n_resamples=0), dataroot=root, version=VERSION).planning
    after = evaluate_loaded([run], resampling=Resampling(n_resamples=0), dataroot=data, version=VERSION).planning
    label = next(k for k in after.runs if k != P.GT_LABEL)
    for who in (label, P.GT_LABEL):
        b, a = before.runs[who], after.runs[who]
        j = a.frame_ids.index(frame)
        assert b.values["nc"][j] == 1.0 and a.values["nc"][j] == 0.5, who
        assert a.reasons["nc"][j] is None
        other = np.array(["cruise" not in f for f in a.frame_ids])  # the other scenes: unchanged, none n/a
        np.testing.assert_array_equal(a.values["nc"][other], b.values["nc"][other])
        assert not any(r and "refused" in r for r in a.reasons["nc"])
    # the safety metrics read the same agents as before
    s_before, s_after = load_safety_data(root, VERSION), load_safety_data(data, VERSION)
    assert s_after.objects == {} and all(np.array_equal(s_before.boxes[k], s_after.boxes[k]) for k in s_before.boxes)
    planning = load_safety_data(data, VERSION, history=P.HISTORY_KEYFRAMES)
    assert sum(len(v) for v in planning.objects.values()) == len(scene) + 1
