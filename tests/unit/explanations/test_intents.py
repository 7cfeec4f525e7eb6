"""The stated intent of stage 2 (rust/intent.rs, rules intent@lightemma/1) and its consistency with the plan of stage 3
(python/lightemma/explanations.py; docs/parsing.md#intents, docs/definitions.md#explanation-audit)."""

from __future__ import annotations

import itertools
import json
import re
import threading

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import lightemma
from lightemma import explanations as ex
from lightemma.evaluation.stats import Resampling
from lightemma.evaluation.synthetic import make_record
from lightemma.pipeline import run
from lightemma.runs.store import FRAMES_FILE, create_run_dir
from tests.support.fake_openai import FakeOpenAIServer, Reply
from tests.support.intent_corpus import CORPUS

U = "unknown"


# ---------------------------------------------------------------- reading: the hand-labelled corpus


def test_corpus_is_read_as_labelled():
    assert len(CORPUS) >= 100
    got = ex.read_intents([t for t, _, _ in CORPUS])
    wrong = [
        f"{t[:80]!r}: want ({lon}, {lat}), got ({got.longitudinal[i]}, {got.lateral[i]}) — {got.reason[i]}"
        for i, (t, lon, lat) in enumerate(CORPUS)
        if (got.longitudinal[i], got.lateral[i]) != (lon, lat)
    ]
    assert not wrong, "\n".join(wrong)


def test_corpus_covers_every_class_and_unknown():
    lon = {c[1] for c in CORPUS}
    lat = {c[2] for c in CORPUS}
    assert set(ex.LONGITUDINAL) | {U} <= lon
    assert set(ex.LATERAL) | {U} <= lat


def test_classes_and_rules():
    assert ex.INTENT_RULES == "intent@lightemma/1"
    assert ex.LONGITUDINAL == ("accelerate", "keep_speed", "decelerate", "stop", "stay_stopped", "start")
    assert ex.LATERAL == ("follow_lane", "turn_left", "turn_right", "change_lane_left", "change_lane_right")
    assert lightemma.read_intents is ex.read_intents
    assert lightemma.intent_consistency is ex.intent_consistency
    assert "read_intents" in lightemma.__all__


def test_every_class_comes_with_its_sentence_and_every_unknown_with_a_reason():
    got = ex.read_intents([t for t, _, _ in CORPUS])
    for i, (text, _, _) in enumerate(CORPUS):
        flat = text.replace("\u2019", "'")
        for axis, cls, sentence in (
            ("longitudinal", got.longitudinal[i], got.longitudinal_sentence[i]),
            ("lateral", got.lateral[i], got.lateral_sentence[i]),
        ):
            if cls == U:
                assert sentence == ""
                assert got.reason[i], text
                assert axis in got.reason[i] or "text" in got.reason[i], got.reason[i]
            else:
                assert sentence and sentence in flat, (text, sentence)


def test_the_planned_part_not_the_recap():
    text = (
        "The ego vehicle has been accelerating strongly and turning left over the past 3 seconds. "
        "Given the red light, it should now decelerate and keep its lane."
    )
    got = ex.read_intents(text)
    assert (got.longitudinal[0], got.lateral[0]) == ("decelerate", "follow_lane")
    assert got.longitudinal_sentence[0] == "Given the red light, it should now decelerate and keep its lane"
    recap_only = ex.read_intents("The ego vehicle has been accelerating and turning left.")
    assert (recap_only.longitudinal[0], recap_only.lateral[0]) == (U, U)
    assert "recap" in recap_only.reason[0]


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("The ego vehicle should not accelerate.", ["longitudinal", "negated 'not accelerate'"]),
        ("If the light turns green, proceed straight.", ["lateral", "conditional"]),
        ("Be prepared to stop.", ["longitudinal", "conditional or hedged 'stop'"]),
        (
            "The ego vehicle should accelerate. The ego vehicle should decelerate.",
            ["contradictory statements 'accelerate' (accelerate) and 'decelerate' (decelerate)"],
        ),
        ("The car ahead will turn right.", ["about another road user 'turn right'"]),
        ("", ["empty text"]),
        ("x" * 70_000, ["text too long: 70000 bytes (limit 65536)"]),
        ("The ego vehicle should stop\ufffd.", ["not valid UTF-8"]),
        ("The ego vehicle should stop\ud800.", ["not valid UTF-8 (lone surrogates)"]),
        ("\x00\x01binary\x02 stop", ["control characters"]),
        ("Answer in one paragraph of plain text. The ego vehicle should stop.", ["echoes the stage-2 prompt"]),
        ("Le véhicule doit ralentir et rester dans sa voie à l'approche du carrefour.", ["not English"]),
        ("<think>I should stop", ["reasoning block"]),
    ],
)
def test_unknown_with_its_reason(text, words):
    got = ex.read_intents([text])
    assert (got.longitudinal[0], got.lateral[0]) == (U, U) or "ignored" not in got.reason[0]
    for w in words:
        assert w in got.reason[0], got.reason[0]


def test_ignored_statements_are_named_beside_the_firm_one():
    got = ex.read_intents("Decelerate, and stop if the pedestrian steps onto the road.")
    assert got.longitudinal[0] == "decelerate"
    assert (
        got.reason[0]
        == "longitudinal: ignored conditional or hedged 'stop'; lateral: no lateral intent stated in the planned part"
    )


def test_inputs():
    assert ex.read_intents("Stop.").longitudinal.tolist() == ["stop"]
    assert ex.read_intents(np.array(["Stop.", "Turn left."])).lateral.tolist() == [U, "turn_left"]
    missing = ex.read_intents(["Stop.", None])
    assert missing.longitudinal.tolist() == ["stop", U] and missing.reason[1] == "no stage-2 text"
    assert len(ex.read_intents([])) == 0
    with pytest.raises(ValueError, match="item 1 is int"):
        ex.read_intents(["Stop.", 3])
    with pytest.raises(ValueError, match="1-D"):
        ex.read_intents(np.array([["Stop."]]))
    with pytest.raises(ValueError, match="got bytes"):
        ex.read_intents(b"Stop.")


def test_large_batches_read_as_small_ones():
    texts = [t for t, _, _ in CORPUS] * 40  # past the parallel threshold
    big, small = ex.read_intents(texts), ex.read_intents(texts[: len(CORPUS)])
    assert big.longitudinal.tolist() == small.longitudinal.tolist() * 40
    assert big.reason == small.reason * 40


# ---------------------------------------------------------------- reading: fuzzed

_WORDS = [
    "the",
    "ego",
    "vehicle",
    "should",
    "will",
    "not",
    "if",
    "has",
    "been",
    "was",
    "accelerate",
    "decelerate",
    "slow",
    "down",
    "stop",
    "remain",
    "stopped",
    "start",
    "moving",
    "maintain",
    "speed",
    "keep",
    "lane",
    "turn",
    "left",
    "right",
    "change",
    "lanes",
    "to",
    "merge",
    "into",
    "straight",
    "or",
    "and",
    "then",
    "may",
    "car",
    "ahead",
    "while",
    "past",
    "next",
    "plan",
    "recent",
    "brake",
    "cruise",
    "halt",
    "é",
    "停",
    "3.5",
    "m/s",
]
_PUNCT = [
    " ",
    " ",
    " ",
    ". ",
    ", ",
    "; ",
    ": ",
    "\n",
    "!",
    "?",
    " - ",
    "<think>",
    "</think>",
    "<think>",
    "</think>",
    "’",
    "\u2014",
    "\ud800",
    "\x00",
]
_fragments = st.lists(st.one_of(st.sampled_from(_WORDS), st.sampled_from(_PUNCT), st.text(max_size=3)), max_size=60)


@settings(max_examples=1000, deadline=None)
@given(_fragments)
def test_fuzz_never_crashes_and_never_reads_without_a_source(parts):
    text = "".join(parts)
    got = ex.read_intents([text])
    assert got.longitudinal[0] in (*ex.LONGITUDINAL, U)
    assert got.lateral[0] in (*ex.LATERAL, U)
    for cls, sentence in (
        (got.longitudinal[0], got.longitudinal_sentence[0]),
        (got.lateral[0], got.lateral_sentence[0]),
    ):
        if cls == U:
            assert got.reason[0]
        else:
            assert sentence and sentence in text.replace("\u2019", "'").replace("\u2018", "'")


_PLAIN = [(t, lon, lat) for t, lon, lat in CORPUS if (lon != U or lat != U)]
_SINGLE = [
    (t, lon, lat)
    for t, lon, lat in _PLAIN
    if t.count(".") == 1
    and t.endswith(".")
    and not any(c in t for c in ":\n<;")
    and "ignored" not in ex.read_intents(t).reason[0]
]


@pytest.mark.parametrize(("text", "lon", "lat"), _PLAIN)
def test_a_recap_put_first_changes_nothing(text, lon, lat):
    got = ex.read_intents(
        "The ego vehicle has been accelerating hard and turning right for the last 3 seconds. " + text
    )
    assert (got.longitudinal[0], got.lateral[0]) == (lon, lat)


@pytest.mark.parametrize(("text", "lon", "lat"), _SINGLE)
def test_a_condition_put_first_makes_both_unknown(text, lon, lat):
    got = ex.read_intents("If the road is clear, " + text[0].lower() + text[1:])
    assert (got.longitudinal[0], got.lateral[0]) == (U, U), got.reason[0]


@pytest.mark.parametrize(
    "verb", ["accelerate", "slow down", "stop", "turn left", "change lanes to the right", "speed up", "brake"]
)
@pytest.mark.parametrize("negation", ["Do not", "Don’t", "Never", "The ego vehicle should not", "Avoid the need to"])
def test_negated_cues_are_never_read(verb, negation):
    got = ex.read_intents(f"{negation} {verb}.")
    assert (got.longitudinal[0], got.lateral[0]) == (U, U)
    assert "negated" in got.reason[0]


def test_corpus_has_at_least_100_texts_in_each_style_family():
    texts = [t for t, _, _ in CORPUS]
    assert sum(len(t) < 60 for t in texts) >= 20  # terse
    assert sum(len(t) > 150 for t in texts) >= 10  # verbose
    assert sum("has been" in t or "was " in t for t in texts) >= 10  # with recaps
    assert (
        sum(t.lower().startswith(("if ", "once ", "when ", "should ", "in case")) or " if " in t for t in texts) >= 8
    )  # conditionals


# ---------------------------------------------------------------- the planned intent


def _plans(rows):
    """rows: (current speed, six speeds, six curvatures) → actions (N, 6, 2), history (N, 6, 2)."""
    actions = np.array([np.stack([np.asarray(v, float), np.asarray(c, float)], axis=1) for _, v, c in rows])
    history = np.array([np.tile([[v0, 0.0]], (6, 1)) for v0, _, _ in rows])
    return actions, history


_STRAIGHT = [0.0] * 6
_PLANNED = [
    ((8, [8] * 6, _STRAIGHT), "keep_speed", "follow_lane"),
    ((8, [7.5, 7, 6.5, 6, 5.5, 5], _STRAIGHT), "decelerate", "follow_lane"),
    ((5, [5.5, 6, 6.5, 7, 7.5, 8], _STRAIGHT), "accelerate", "follow_lane"),
    ((8, [6, 4, 2, 1, 0.2, 0], _STRAIGHT), "stop", "follow_lane"),
    ((0, [0] * 6, _STRAIGHT), "stay_stopped", U),  # no path: lateral unknown
    ((0.2, [0.5, 1, 1.5, 2, 2.5, 3], _STRAIGHT), "start", "follow_lane"),
    ((8, [8] * 6, [0.05] * 6), "keep_speed", "turn_left"),
    ((8, [8] * 6, [-0.05] * 6), "keep_speed", "turn_right"),
    ((8, [8] * 6, [0.03, 0.03, 0, -0.03, -0.03, 0]), "keep_speed", "change_lane_left"),
    ((8, [8] * 6, [-0.03, -0.03, 0, 0.03, 0.03, 0]), "keep_speed", "change_lane_right"),
    ((8, [8] * 6, [0.01] * 6), "keep_speed", "follow_lane"),  # a gentle curve: 0.24 rad, the lane may bend
    ((8, [8.1, 8.2, 8.3, 8.4, 8.5, 8.6], _STRAIGHT), U, "follow_lane"),  # +0.2 m/s²: borderline
    ((8, [8] * 6, [0.0075, 0.0075, 0, -0.0075, -0.0075, 0]), "keep_speed", U),  # 0.7 m beyond the arc: borderline
]


@pytest.mark.parametrize(("row", "lon", "lat"), _PLANNED)
def test_planned_classes(row, lon, lat):
    actions, history = _plans([row])
    got = ex.planned_intents(actions, history)
    assert (got.longitudinal[0], got.lateral[0]) == (lon, lat), (
        got.reason[0],
        got.heading_change[0],
        got.arc_excess[0],
    )
    if U in (lon, lat):
        assert "borderline" in got.reason[0] or "path of" in got.reason[0]


def test_planned_measures_and_given_trajectory():
    actions, history = _plans([(8, [7.5, 7, 6.5, 6, 5.5, 5], [0.05] * 6)])
    got = ex.planned_intents(actions, history)
    assert got.initial_speed[0] == 8 and got.final_speed[0] == 5
    assert got.mean_acceleration[0] == pytest.approx(-1.0)
    assert got.path_length[0] == pytest.approx(18.75)
    assert got.heading_change[0] == pytest.approx(0.05 * 37.5 * 0.5)
    mirrored = lightemma.integrate(actions) * np.array([1.0, -1.0])  # a trajectory that curves right
    assert ex.planned_intents(actions, history, trajectory=mirrored).side[0] == 1  # the heading still says left
    assert ex.planned_intents(actions, history, trajectory=mirrored).arc_excess[0] < -ex.Thresholds().lane_change


def test_planned_unknown_without_numbers_and_shape_errors():
    actions, history = _plans([(8, [8] * 6, _STRAIGHT)] * 3)
    actions[1, 2, 0] = np.nan
    history[2, -1, 0] = np.nan
    got = ex.planned_intents(actions, history)
    assert got.longitudinal.tolist() == ["keep_speed", U, U]
    assert got.lateral.tolist() == ["follow_lane", U, "follow_lane"]
    assert got.reason[1] == "no planned actions (failed or non-finite)"
    assert got.reason[2] == "longitudinal: no current speed (history)"
    with pytest.raises(ValueError, match=r"history must have shape \(3, T, 2\)"):
        ex.planned_intents(actions, history[:2])
    with pytest.raises(ValueError, match="actions must have shape"):
        ex.planned_intents(actions[0], history)


# ---------------------------------------------------------------- consistency per frame


_CHECKS = [
    ("The ego vehicle should come to a stop.", (8, [8] * 6, _STRAIGHT), "contradicts", "says stop, plans keep_speed"),
    (
        "Turn left at the intersection.",
        (8, [8] * 6, [-0.05] * 6),
        "contradicts",
        "says turn_left, plans turn_right to the right",
    ),
    (
        "Change lanes to the left.",
        (8, [8] * 6, [-0.03, -0.03, 0, 0.03, 0.03, 0]),
        "contradicts",
        "says change_lane_left",
    ),
    (
        "Keep your lane and maintain speed.",
        (8, [8] * 6, [0.03, 0.03, 0, -0.03, -0.03, 0]),
        "contradicts",
        "says follow_lane, plans change_lane_left",
    ),
    ("Accelerate.", (8, [7, 6, 5, 4, 3, 2], _STRAIGHT), "contradicts", "says accelerate, plans decelerate"),
    ("Slow down and stay in lane.", (8, [7.5, 7, 6.5, 6, 5.5, 5], _STRAIGHT), "consistent", ""),
    ("Slow down.", (8, [6, 4, 2, 1, 0.2, 0], _STRAIGHT), "consistent", "lateral: no stated lateral intent"),
    ("Come to a stop.", (8, [7.5, 7, 6.5, 6, 5.5, 5], _STRAIGHT), "consistent", "lateral: no stated lateral intent"),
    ("Start moving and go straight.", (0, [0.5, 1, 1.5, 2, 2.5, 3], _STRAIGHT), "consistent", ""),
    ("Turn left.", (8, [8] * 6, [0.05] * 6), "consistent", "longitudinal: no stated longitudinal intent"),
    ("Turn left.", (8, [8] * 6, _STRAIGHT), U, "may begin after the horizon"),
    ("Follow the lane.", (8, [8] * 6, [0.05] * 6), U, "the lane may bend"),
    ("Maintain speed.", (8, [8.1, 8.2, 8.3, 8.4, 8.5, 8.6], _STRAIGHT), U, "borderline"),
    ("The ego vehicle should not accelerate.", (8, [8] * 6, _STRAIGHT), U, "negated"),
    ("", (8, [8] * 6, _STRAIGHT), U, "empty text"),
    ("Stop.", (8, [np.nan] * 6, _STRAIGHT), U, "no planned actions"),
    # a consistent axis beside a self-contradicting one is no consistent frame
    ("Slow down. Turn left, then turn right.", (8, [7.5, 7, 6.5, 6, 5.5, 5], _STRAIGHT), U, "contradictory statements"),
]


@pytest.mark.parametrize(("text", "row", "verdict", "why"), _CHECKS)
def test_verdicts(text, row, verdict, why):
    actions, history = _plans([row])
    got = ex.intent_consistency([text], actions, history)
    assert got.verdict[0] == verdict, got.reason[0]
    assert why in got.reason[0]
    if verdict == "consistent" and not why:
        assert got.reason[0] == ""


def test_an_unknown_statement_is_never_consistent():
    texts = ["", "If the light turns green, accelerate.", "The road is clear.", "停车", "Do not turn left."] * 3
    rows = [(8, [8] * 6, _STRAIGHT), (8, [9, 10, 11, 12, 13, 14], _STRAIGHT), (0, [0] * 6, _STRAIGHT)] * 5
    actions, history = _plans(rows)
    got = ex.intent_consistency(texts, actions, history)
    assert set(got.verdict.tolist()) == {U}


def test_consistency_inputs():
    actions, history = _plans([(8, [8] * 6, _STRAIGHT)] * 2)
    with pytest.raises(ValueError, match="1 stated intent"):
        ex.intent_consistency(["Stop."], actions, history)
    stated = ex.read_intents(["Stop.", "Accelerate."])
    assert ex.intent_consistency(stated, actions, history).verdict.tolist() == ["contradicts", "contradicts"]


# ---------------------------------------------------------------- runs whose answers contradict their actions at known frames

_HONEST = [
    ("The ego vehicle has been cruising. It should keep its speed and follow the lane.", (8, [8] * 6, _STRAIGHT)),
    ("The ego vehicle should slow down and stay in its lane.", (8, [7.5, 7, 6.5, 6, 5.5, 5], _STRAIGHT)),
    ("Turn left at the junction while slowing down.", (8, [7, 6.5, 6, 5.5, 5, 5], [0.08] * 6)),
    ("Accelerate gently and keep the lane.", (5, [5.5, 6, 6.5, 7, 7.5, 8], _STRAIGHT)),
]
_LIES = {
    3: ("The ego vehicle should come to a complete stop and stay in its lane.", (8, [8] * 6, _STRAIGHT)),
    10: ("The ego vehicle should turn left.", (8, [8] * 6, [-0.05] * 6)),
    17: ("Slow down and keep the lane.", (6, [7, 8, 9, 10, 11, 12], _STRAIGHT)),
}


def _write_run(root, model, lies, scenes=4, per_scene=6):
    run_dir = create_run_dir(
        root, model, {"model": model, "started_at": "2026-01-01T00:00:00+00:00", "integrator": "euler"}
    )
    records = []
    for k in range(scenes * per_scene):
        text, row = lies.get(k, _HONEST[k % len(_HONEST)])
        actions, history = _plans([row])
        traj = lightemma.integrate(actions)[0]
        records.append(
            make_record(
                f"scene-{k // per_scene:04d}/{k % per_scene}",
                traj,
                traj,
                actions=actions[0],
                history_actions=history[0],
                scene_name=f"scene-{k // per_scene:04d}",
                texts={"intent": text, "answer": "[]"},
            )
        )
    (run_dir / FRAMES_FILE).write_text("".join(json.dumps(r) + "\n" for r in records), encoding="utf-8")
    return run_dir


def test_run_contradictions_at_the_known_frames(tmp_path):
    honest = ex.run_consistency(_write_run(tmp_path, "honest", {}))
    liar = ex.run_consistency(_write_run(tmp_path, "liar", _LIES))
    assert set(honest.consistency.verdict.tolist()) == {"consistent"}
    contradicts = [i for i, v in enumerate(liar.consistency.verdict) if v == "contradicts"]
    assert [liar.frame_ids[i] for i in contradicts] == ["scene-0000/3", "scene-0001/4", "scene-0002/5"]
    assert liar.consistency.reason[3] == "longitudinal: says stop, plans keep_speed"
    assert "lateral: says turn_left, plans turn_right" in liar.consistency.reason[10]
    assert liar.consistency.reason[17] == "longitudinal: says decelerate, plans accelerate"

    summary = ex.summarize_consistency([("honest", honest), ("liar", liar)], Resampling(n_resamples=2000))
    assert summary["rules"] == "intent@lightemma/1"
    h, lie = summary["models"]
    assert (h["frames"], h["consistent"], h["contradicts"], h["scenes"]) == (24, 24, 0, 4)
    assert (lie["consistent"], lie["contradicts"], lie["unknown"]) == (21, 3, 0)
    assert lie["contradiction_rate"] == pytest.approx(3 / 24)
    low, high = lie["contradiction_ci"]
    assert low <= 3 / 24 <= high and high > low
    assert h["contradiction_ci"] == [0.0, 0.0]
    lon = lie["confusion"]["longitudinal"]
    counts = np.array(lon["counts"])
    assert counts.sum() == 24
    assert counts[lon["stated"].index("stop"), lon["planned"].index("keep_speed")] == 1
    assert counts[lon["stated"].index("decelerate"), lon["planned"].index("accelerate")] == 1
    lat = lie["confusion"]["lateral"]
    assert np.array(lat["counts"])[lat["stated"].index("turn_left"), lat["planned"].index("turn_right")] == 1
    (pair,) = summary["pairs"]
    assert (pair["a"], pair["b"], pair["frames"], pair["scenes"]) == ("honest", "liar", 24, 4)
    assert pair["contradiction_diff"] == pytest.approx(-3 / 24)
    assert pair["consistency_diff"] == pytest.approx(3 / 24)
    assert 0 < pair["contradiction_p"] <= 1 and pair["contradiction_p_holm"] >= pair["contradiction_p"]


def test_summary_labels_must_differ(tmp_path):
    run = ex.run_consistency(_write_run(tmp_path, "m", {}))
    with pytest.raises(ValueError, match="duplicate model label"):
        ex.summarize_consistency([("m", run), ("m", run)])


def test_failed_stage_and_failed_parse_are_unknown(tmp_path):
    run_dir = _write_run(tmp_path, "broken", {})
    lines = (run_dir / FRAMES_FILE).read_text(encoding="utf-8").splitlines()
    first, second = json.loads(lines[0]), json.loads(lines[1])
    first["intent_text"] = None
    second["actions"], second["trajectory"], second["status"] = None, None, "failed"
    lines[0], lines[1] = json.dumps(first), json.dumps(second)
    (run_dir / FRAMES_FILE).write_text("\n".join(lines) + "\n", encoding="utf-8")
    run = ex.run_consistency(run_dir)
    assert run.consistency.verdict[:2].tolist() == [U, U]
    assert "no stage-2 text" in run.consistency.reason[0]
    assert "no planned actions" in run.consistency.reason[1]


# ---------------------------------------------------------------- a real run (lightemma synth, a loopback model) that lies at known frames

LIE = "The ego vehicle has been driving in its lane. It should come to a complete stop."
HONEST = "The ego vehicle has been driving in its lane. It should maintain its current speed and keep its lane."


def test_a_run_through_the_pipeline_whose_model_lies_at_known_frames(tmp_path, synth_root):
    counter, lock = itertools.count(), threading.Lock()

    def model(req):
        if req.stage == "scene":
            return Reply("A quiet street with parked cars.")
        if req.stage == "intent":
            with lock:
                k = next(counter)
            return Reply(LIE if k % 3 == 0 else HONEST)
        prompt = req.text
        history = prompt.split("Driving intent", 1)[0]
        v0 = float(re.findall(r"\(\s*(-?[\d.]+(?:e-?\d+)?)\s*,", history)[-1])
        # the liar said stop and plans to speed up by 3 m/s; the honest model keeps its speed and lane
        v = v0 + 3.0 if "complete stop" in prompt else v0
        return Reply("[" + ", ".join(f"({v:.3f}, 0.0)" for _ in range(6)) + "]")

    with FakeOpenAIServer(model) as server:
        result = run(
            "openai/gpt-4o",
            api_base=server.url,
            dataroot=synth_root,
            version="v1.0-mini",
            output=tmp_path / "runs",
            backoff_base=0.01,
            backoff_cap=0.05,
            timeout=10.0,
            progress=False,
        )
    got = ex.run_consistency(result.run_dir)
    records = {
        r["frame_id"]: r for r in (json.loads(line) for line in (result.run_dir / FRAMES_FILE).read_text().splitlines())
    }
    lied = sorted(fid for fid, r in records.items() if r["intent_text"] == LIE)
    assert 0 < len(lied) < len(records) == len(got.frame_ids) == 12
    verdict = dict(zip(got.frame_ids, got.consistency.verdict.tolist(), strict=True))
    assert sorted(fid for fid, v in verdict.items() if v == "contradicts") == lied
    for i, fid in enumerate(got.frame_ids):
        if fid in lied:
            assert got.consistency.reason[i].startswith("longitudinal: says stop, plans "), got.consistency.reason[i]
        else:  # consistent, or unknown only where the plan is too short to show a lane (a standing car)
            assert verdict[fid] == "consistent" or "path of" in got.consistency.reason[i], got.consistency.reason[i]
    summary = ex.summarize_consistency([("gpt-4o", got)], Resampling(n_resamples=500))
    assert summary["models"][0]["contradicts"] == len(lied)
