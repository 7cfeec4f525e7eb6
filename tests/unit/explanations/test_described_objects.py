"""Described objects against the annotations (issue 36 item 4; rust/objects.rs, lightemma.explanations.read_objects,
lightemma.evaluation.object_audit, docs/definitions.md#described-objects): the reader on a hand-labelled corpus and bad
input, the CAM_FRONT states against a hand projection on `lightemma synth` data, the checks and rates by hand, and the
audit end to end through `lightemma evaluate` with a loopback model."""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lightemma.evaluation.object_audit import (
    ABSENT,
    AMBIGUOUS,
    CHECKED,
    PRESENT,
    RANGE_M,
    audit_run,
    front_objects,
    object_check,
    object_rows,
)
from lightemma.evaluation.safety import sample_token_of
from lightemma.evaluation.stats import Resampling
from lightemma.explanations import OBJECT_CLASSES, read_objects
from tests.support.object_corpus import CORPUS

VERSION = "v1.0-mini"


# -- the reader ----------------------------------------------------------------------------------------------------


def test_the_hand_labelled_corpus_is_read_as_labelled():
    assert len(CORPUS) >= 40
    got = read_objects([t for t, _, _ in CORPUS])
    wrong = []
    for i, (text, labels, counts) in enumerate(CORPUS):
        for j, cls in enumerate(OBJECT_CLASSES):
            want = (labels.get(cls, "not_mentioned"), counts.get(cls, -1))
            have = (str(got.mentions[i, j]), int(got.counts[i, j]))
            if want != have:
                wrong.append((text[:60], cls, want, have))
    assert not wrong, wrong
    # every mention kind occurs, so the corpus tests each of them
    assert {"affirmed", "negated", "hedged", "not_mentioned"} <= set(got.mentions.ravel().tolist())


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("", "empty text"),
        (None, "no stage-1 text"),
        ("a " * 40_000, "too long"),
        ("Ein Fußgänger überquert die Straße vor dem Auto und ein Radfahrer wartet", "not English"),
        ("You are an expert labeller of autonomous-driving data. A car.", "echoes the prompt"),
        ("A car \x00\x01 ahead", "control characters"),
        ("A pedestrian \ud800 ahead", "not valid UTF-8"),
        ("<think>a pedestrian is there", "reasoning block"),
    ],
)
def test_bad_input_is_unknown_on_every_class_with_the_reason(text, why):
    got = read_objects([text])
    assert set(got.mentions[0].tolist()) == {"unknown"}
    assert why in got.reason[0]


def test_a_text_that_is_not_str_is_refused_by_position():
    with pytest.raises(ValueError, match="item 1 is int"):
        read_objects(["A car.", 3])


# -- the annotations in view: a hand projection on synthetic data ------------------------------------------------------


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """7 synthetic scenes (the sixth, right-turn, has pedestrians beside the road), 20 keyframes, 64 × 36 images."""
    from lightemma.synth import write_dataset

    return write_dataset(tmp_path_factory.mktemp("objects"), scenes=7, keyframes=20, image_size=(64, 36), sweeps=False)


def _tables(root):
    return {
        name: json.loads((root / VERSION / f"{name}.json").read_text(encoding="utf-8"))
        for name in ("sample", "sample_data", "ego_pose", "sample_annotation", "instance", "category", "visibility")
    }


def _hand_states(root) -> dict[str, np.ndarray]:
    """PRESENT / ABSENT / AMBIGUOUS of pedestrian and car per sample, by hand: planar yaw rotations (the synthetic
    poses and boxes are planar), corners by cos/sin, the synthetic camera's own ego_to_cam and project."""
    from lightemma.synth.camera import Camera

    cam = Camera(width=64, height=36)
    t = _tables(root)
    pose_of = {p["token"]: p for p in t["ego_pose"]}
    ego = {sd["sample_token"]: pose_of[sd["ego_pose_token"]] for sd in t["sample_data"] if sd["is_key_frame"]}
    cat = {c["token"]: c["name"] for c in t["category"]}
    inst = {i["token"]: cat[i["category_token"]] for i in t["instance"]}
    level = {v["token"]: v["level"] for v in t["visibility"]}

    def yaw(q):
        return 2.0 * math.atan2(q[3], q[0])  # a rotation about z only

    out = {}
    for s in t["sample"]:
        st = s["token"]
        p = ego[st]
        ex, ey, eyaw = p["translation"][0], p["translation"][1], yaw(p["rotation"])
        states = np.full(2, ABSENT, dtype=np.int8)
        for ann in t["sample_annotation"]:
            if ann["sample_token"] != st:
                continue
            name = inst[ann["instance_token"]]
            cls = 0 if name.startswith("human.pedestrian.adult") else 1 if name == "vehicle.car" else None
            if cls is None:
                continue
            w, length, h = ann["size"]
            (bx, by, bz), byaw = ann["translation"], yaw(ann["rotation"])
            pts = []
            for sx, sy, sz in [(a, b, c) for a in (1, -1) for b in (1, -1) for c in (1, -1)]:
                gx = bx + math.cos(byaw) * sx * length / 2 - math.sin(byaw) * sy * w / 2
                gy = by + math.sin(byaw) * sx * length / 2 + math.cos(byaw) * sy * w / 2
                dx, dy = gx - ex, gy - ey
                pts.append(
                    [
                        math.cos(eyaw) * dx + math.sin(eyaw) * dy,
                        -math.sin(eyaw) * dx + math.cos(eyaw) * dy,
                        bz + sz * h / 2,
                    ]
                )
            c = cam.ego_to_cam(np.array(pts))
            uv = cam.project(np.where(c[:, 2:3] > 0, c, 1.0))
            seen = ((c[:, 2] > 1.0) & (uv[:, 0] > 0) & (uv[:, 0] < 64) & (uv[:, 1] > 0) & (uv[:, 1] < 36)).any()
            if not seen:
                continue
            dx, dy = bx - ex, by - ey
            near = math.hypot(dx, dy) <= (RANGE_M["pedestrian"] if cls == 0 else RANGE_M["car"])
            if near and level[ann["visibility_token"]] != "v0-40":
                states[cls] = PRESENT
            elif states[cls] != PRESENT:
                states[cls] = AMBIGUOUS
        out[st] = states
    return out


def test_states_match_a_hand_projection(dataset):
    samples = {s["token"] for s in _tables(dataset)["sample"]}
    front = front_objects(dataset, VERSION, samples)
    hand = _hand_states(dataset)
    assert front.annotated and not front.reasons
    cols = [CHECKED.index("pedestrian"), CHECKED.index("car")]
    mine = {st: front.states[st][cols] for st in samples}
    assert all(np.array_equal(mine[st], hand[st]) for st in samples), [
        (st, mine[st], hand[st]) for st in samples if not np.array_equal(mine[st], hand[st])
    ][:5]
    # not vacuous: pedestrians and cars are both in view somewhere and absent elsewhere
    stacked = np.stack([hand[st] for st in samples])
    for k in range(2):
        assert (stacked[:, k] == PRESENT).any() and (stacked[:, k] == ABSENT).any()


def test_low_visibility_an_indefinite_category_and_a_bad_box(dataset, tmp_path):
    root = tmp_path / "copy"
    shutil.copytree(dataset, root, ignore=shutil.ignore_patterns("samples", "sweeps", "maps"))
    t = _tables(root)
    samples = {s["token"] for s in t["sample"]}
    before = front_objects(root, VERSION, samples)
    ped = CHECKED.index("pedestrian")
    st = next(s for s in sorted(samples) if before.states[s][ped] == PRESENT)
    inst = {i["token"]: i for i in t["instance"]}
    cat = {c["token"]: c["name"] for c in t["category"]}
    anns = t["sample_annotation"]
    for ann in anns:  # every pedestrian of that sample under 40 % visible
        if ann["sample_token"] == st and cat[inst[ann["instance_token"]]["category_token"]].startswith("human."):
            ann["visibility_token"] = "1"
    car = CHECKED.index("car")
    st_car = next(s for s in sorted(samples) if before.states[s][car] == PRESENT and s != st)
    police = {"token": "police-category", "name": "vehicle.emergency.police", "description": ""}
    t["category"].append(police)
    for ann in anns:  # the cars of another sample become police cars: "car" or not is a guess
        if ann["sample_token"] == st_car and cat[inst[ann["instance_token"]]["category_token"]] == "vehicle.car":
            inst[ann["instance_token"]]["category_token"] = police["token"]
    st_bad = next(s for s in sorted(samples) if s not in (st, st_car) and any(a["sample_token"] == s for a in anns))
    next(a for a in anns if a["sample_token"] == st_bad)["size"] = [0.0, 4.0, 1.5]
    for name in ("sample_annotation", "instance", "category"):
        (root / VERSION / f"{name}.json").write_text(json.dumps(t[name]), encoding="utf-8")
    after = front_objects(root, VERSION, samples)
    assert after.states[st][ped] == AMBIGUOUS
    assert after.states[st_car][car] == AMBIGUOUS
    assert st_bad not in after.states and "degenerate box" in after.reasons[st_bad]


# -- the checks and the rates, by hand ---------------------------------------------------------------------------------


def _mentions(rows: list[dict[str, str]]) -> np.ndarray:
    return np.array([[r.get(c, "not_mentioned") for c in OBJECT_CLASSES] for r in rows], dtype=object).astype(str)


def test_checks_and_tags_by_hand():
    P, A, X = PRESENT, ABSENT, AMBIGUOUS
    ped, car = CHECKED.index("pedestrian"), CHECKED.index("car")
    mentions = _mentions(
        [
            {"pedestrian": "affirmed"},  # 0: pedestrian absent -> hallucinated
            {"pedestrian": "affirmed"},  # 1: present -> correct
            {},  # 2: present, not mentioned -> missed
            {"pedestrian": "negated"},  # 3: present, negated -> missed
            {"pedestrian": "hedged"},  # 4: present, hedged -> neither (no answer)
            {"pedestrian": "affirmed", "car": "affirmed"},  # 5: ambiguous -> neither
        ]
    )
    states = np.full((6, len(CHECKED)), A, dtype=np.int8)
    states[[1, 2, 3, 4], ped] = P
    states[5, ped] = X
    states[5, car] = P
    check = object_check(mentions, states)
    assert check.hallucinated_pedestrian.tolist() == [True, False, False, False, False, False]
    assert check.missed_pedestrian.tolist() == [False, False, True, True, False, False]
    assert check.precision_eligible[:, ped].tolist() == [True, True, False, False, False, False]
    assert check.recall_eligible[:, ped].tolist() == [False, True, True, True, False, False]
    assert check.correct[:, car].tolist() == [False] * 5 + [True]
    with pytest.raises(ValueError, match="mentions must be"):
        object_check(mentions[:, :3], states)


def test_rates_by_hand_and_na_with_reasons():
    from lightemma.evaluation.object_audit import FrontObjects

    ped = CHECKED.index("pedestrian")
    ids = [f"scene-{k % 3}/tok{k}" for k in range(6)]
    front = FrontObjects(annotated=True)
    for k, fid in enumerate(ids):
        s = np.full(len(CHECKED), ABSENT, dtype=np.int8)
        if k < 2:
            s[ped] = PRESENT
        front.states[sample_token_of(fid)] = s
    texts = ["A pedestrian crosses.", "No pedestrians.", "A pedestrian waits.", "A pedestrian waits.", "A car.", None]
    scenes = np.array([f.split("/")[0] for f in ids], dtype=object)
    audit = audit_run(ids, scenes, texts, front)
    baseline = audit_run(ids, scenes, [None] * 6, front)
    rows, classes = object_rows({"m": audit, "b": baseline}, Resampling(n_resamples=200), {"b": "no stage-1 texts"})
    # frames 0-4 are readable (frame 5 has no text); pedestrians affirmed at 0, 2, 3; present at 0, 1
    assert rows["m"]["object_frames"] == 5
    assert rows["m"]["hallucinated_pedestrian"] == pytest.approx(2 / 5)
    assert rows["m"]["missed_pedestrian"] == pytest.approx(1 / 5)
    assert rows["m"]["hallucinated_pedestrian_ci95"] is not None
    by = {(r["model"], r["class"]): r for r in classes}
    p = by[("m", "pedestrian")]
    assert p["mention_precision"] == pytest.approx(1 / 3) and p["mention_recall"] == pytest.approx(1 / 2)
    assert p["mentions"] == 3 and p["in_view"] == 2
    assert by[("m", "car")]["mention_precision"] == 0.0
    assert by[("m", "car")]["mention_recall"] is None and "never in view" in by[("m", "car")]["mention_recall_na"]
    assert by[("m", "traffic_light")]["mention_precision"] is None
    assert "map objects" in by[("m", "traffic_light")]["mention_precision_na"]
    assert rows["b"]["hallucinated_pedestrian"] is None
    assert rows["b"]["hallucinated_pedestrian_na"] == "no stage-1 texts"
    assert by[("b", "pedestrian")]["mention_recall_na"] == "no stage-1 texts"
    assert by[("b", "pedestrian")]["mentions"] is None
    # a version without annotations: n/a with the reason, never 0
    bare = audit_run(ids, scenes, texts, FrontObjects(annotated=False))
    rows, _ = object_rows({"m": bare}, Resampling(n_resamples=0), {})
    assert rows["m"]["hallucinated_pedestrian"] is None and "no annotations" in rows["m"]["hallucinated_pedestrian_na"]


# -- end to end: a loopback model through `lightemma evaluate` ---------------------------------------------------------

SCENE = "A pedestrian is crossing the road ahead, and two cars are parked on the right."


@pytest.fixture(scope="module")
def runs(tmp_path_factory, dataset):
    from lightemma.cli import main
    from lightemma.pipeline import run
    from tests.support.fake_openai import FakeOpenAIServer, Reply

    def model(req):
        if req.stage == "scene":
            return Reply(SCENE)
        if req.stage == "intent":
            return Reply("It should keep its lane and speed.")
        return Reply("[" + ", ".join("(5.000, 0.0)" for _ in range(6)) + "]")

    out = tmp_path_factory.mktemp("objects-runs") / "runs"
    with FakeOpenAIServer(model) as server:
        full = run(
            "openai/gpt-4o",
            api_base=server.url,
            dataroot=dataset,
            version=VERSION,
            output=out,
            backoff_base=0.01,
            backoff_cap=0.05,
            timeout=10.0,
            progress=False,
        ).run_dir
    assert (
        main(
            [
                "run",
                "--model",
                "baseline:cv",
                "--dataroot",
                str(dataset),
                "--version",
                VERSION,
                "--split",
                "all",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    (baseline,) = (out / "baseline-cv").iterdir()
    return full, baseline, out


def test_two_evaluations_merge_with_their_described_objects(runs, tmp_path, capsys):
    from lightemma.cli import main
    from lightemma.pipeline import run
    from tests.support.fake_openai import FakeOpenAIServer, Reply

    full, _, out = runs

    def model(req):
        if req.stage == "scene":
            return Reply("No pedestrians. A bus ahead.")
        if req.stage == "intent":
            return Reply("It should keep its lane and speed.")
        return Reply("[" + ", ".join("(5.000, 0.0)" for _ in range(6)) + "]")

    with FakeOpenAIServer(model) as server:
        other = run(
            "openai/gpt-4o-mini",
            api_base=server.url,
            dataroot=_dataroot(full),
            version=VERSION,
            output=tmp_path / "other",
            backoff_base=0.01,
            backoff_cap=0.05,
            timeout=10.0,
            progress=False,
        ).run_dir
    files = []
    for k, d in enumerate((full, other)):
        capsys.readouterr()
        assert main(["evaluate", str(d), "--format", "json", "--resamples", "0", "--no-safety"]) == 0
        files.append(tmp_path / f"{k}.json")
        files[-1].write_text(capsys.readouterr().out, encoding="utf-8")
    capsys.readouterr()
    assert main(["evaluate", "--merge", *map(str, files)]) == 0
    merged = json.loads(capsys.readouterr().out)
    (objects,) = [t for t in merged["tables"] if t["name"] == "described_objects"]
    assert {r["model"] for r in objects["rows"]} == {"openai/gpt-4o", "openai/gpt-4o-mini"}
    mini = {r["class"]: r for r in objects["rows"] if r["model"] == "openai/gpt-4o-mini"}
    assert mini["pedestrian"]["mentions"] == 0 and mini["bus"]["mention_precision"] == 0.0  # no bus is annotated


def _dataroot(run_dir):
    manifest = json.loads((run_dir / "manifest.json").read_text(encoding="utf-8"))
    return manifest["dataset"]["dataroot"]


def test_evaluate_json_and_markdown_carry_the_object_audit(runs, dataset, capsys):
    from lightemma.cli import main

    full, baseline, _ = runs
    capsys.readouterr()
    assert main(["evaluate", str(full), str(baseline), "--format", "json", "--resamples", "200"]) == 0
    document = json.loads(capsys.readouterr().out)
    (explanations,) = [t for t in document["tables"] if t["name"] == "explanations"]
    rows = {r["model"]: r for r in explanations["rows"]}
    model, base = rows["openai/gpt-4o"], rows["Baseline (constant velocity)"]
    # expected from the hand projection: every frame affirms a pedestrian and two cars
    hand = _hand_states(dataset)
    frames = [json.loads(line)["frame_id"] for line in (full / "frames.jsonl").read_text().splitlines()]
    ped = np.array([hand[sample_token_of(f)][0] for f in frames])
    car = np.array([hand[sample_token_of(f)][1] for f in frames])
    assert (ped == PRESENT).any() and (ped == ABSENT).any()
    assert model["object_frames"] == len(frames)
    assert model["hallucinated_pedestrian"] == pytest.approx(float((ped == ABSENT).mean()))
    assert model["missed_pedestrian"] == 0.0
    assert base["hallucinated_pedestrian"] is None and "no stage-1 texts" in base["hallucinated_pedestrian_na"]
    (objects,) = [t for t in document["tables"] if t["name"] == "described_objects"]
    by = {(r["model"], r["class"]): r for r in objects["rows"]}
    r = by[("openai/gpt-4o", "car")]
    checkable = np.isin(car, (PRESENT, ABSENT)).sum()
    assert r["mention_precision"] == pytest.approx(float((car == PRESENT).sum() / checkable))
    assert r["mention_recall"] == 1.0 and r["mentions"] == len(frames)
    assert by[("openai/gpt-4o", "traffic_light")]["mention_precision"] is None
    # every column has its descriptor (metric id and version)
    described = document["columns"]["described_objects"]
    assert described["mention_precision"]["id"] == "mention_precision@objects_lightemma/1"
    explained = document["columns"]["explanations"]
    assert explained["hallucinated_pedestrian"]["id"] == "hallucinated_pedestrian@objects_lightemma/1"
    capsys.readouterr()
    assert main(["evaluate", str(full), str(baseline), "--resamples", "0"]) == 0
    markdown = capsys.readouterr().out
    assert "Hallucinated pedestrian" in markdown and "Described objects" in markdown


def test_the_scenario_tags(runs, dataset):
    from lightemma.evaluation import evaluate_runs
    from lightemma.evaluation.loading import load_run
    from lightemma.evaluation.scenarios import per_tag_metrics

    full, baseline, _ = runs
    evaluation = evaluate_runs([full, baseline], resampling=Resampling(n_resamples=0), safety=False, planning=False)
    hand = _hand_states(dataset)
    loaded = [load_run(d, details=True) for d in (full, baseline)]
    rows = {r["tag"]: r for r in per_tag_metrics(loaded, explanations=evaluation.explanations)}
    absent = sum(hand[sample_token_of(f)][0] == ABSENT for f in loaded[0].frame_ids)
    assert rows["hallucinated-pedestrian"]["openai/gpt-4o frames"] == absent > 0
    assert rows["missed-pedestrian"]["openai/gpt-4o frames"] == 0
    assert rows["hallucinated-pedestrian"]["Baseline (constant velocity) frames"] == 0


# -- fuzzing -----------------------------------------------------------------------------------------------------------

_WORDS = [
    "a",
    "two",
    "no",
    "not",
    "pedestrian",
    "pedestrians",
    "car",
    "cars",
    "bus",
    "stop",
    "lane",
    "bike",
    "may",
    "watch",
    "for",
    "any",
    "but",
    "and",
    "the",
    "ego",
    ",",
    ".",
    ":",
    "none",
    "clear",
    "of",
    "traffic",
    "light",
    "cones",
    "Straße",
    "<think>",
    "</think>",
    "\n",
]


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(st.sampled_from(_WORDS), st.text(max_size=8)), max_size=40))
def test_fuzz_never_crashes_and_unknown_always_has_a_reason(parts):
    text = " ".join(parts)
    got = read_objects([text, text])
    assert got.mentions.shape == (2, len(OBJECT_CLASSES)) and (got.mentions[0] == got.mentions[1]).all()
    assert set(got.mentions.ravel().tolist()) <= {"affirmed", "negated", "hedged", "not_mentioned", "unknown"}
    unknown = got.mentions[0] == "unknown"
    assert unknown.all() or not unknown.any()
    if unknown.all():
        assert got.reason[0]
    counted = got.counts[0] >= 0
    assert (got.mentions[0][counted] == "affirmed").all()  # a count only for an affirmed class


@settings(max_examples=100, deadline=None)
@given(
    st.sampled_from(["pedestrians", "cyclists", "cars", "trucks", "buses", "traffic cones", "barriers"]),
    st.sampled_from(["There are no", "No", "I see no", "The road is clear of", "There are not any"]),
)
def test_a_negated_class_is_never_affirmed(noun, negation):
    got = read_objects([f"{negation} {noun} in the scene."])
    assert "affirmed" not in got.mentions[0].tolist() and "negated" in got.mentions[0].tolist()


def test_large_batches_read_as_small_ones():
    texts = [t for t, _, _ in CORPUS] * 60  # over the parallel threshold (2,048)
    big = read_objects(texts)
    small = read_objects([t for t, _, _ in CORPUS])
    assert (big.mentions == np.tile(small.mentions, (60, 1))).all()
    assert (big.counts == np.tile(small.counts, (60, 1))).all()
