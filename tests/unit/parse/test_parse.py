"""The answer parser: a corpus of realistic answers, fuzzing, and the public API's contract."""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import lightemma
from tests.support.paper_reference import paper_reference
from tests.support.parse_corpus import CASES, HISTORIES


def _history(name):
    return None if name not in HISTORIES else np.array([HISTORIES[name]], dtype=float)


@pytest.mark.parametrize(("name", "answer", "status", "values", "failure"), CASES, ids=[c[0] for c in CASES])
def test_corpus(name, answer, status, values, failure):
    parsed = lightemma.parse_actions(answer, history=_history(name))
    assert parsed.status[0] == status, parsed.reason[0]
    assert parsed.failure[0] == failure, parsed.reason[0]
    if values is None:
        assert np.isnan(parsed.actions[0]).all()
        assert parsed.reason[0]
    else:
        np.testing.assert_array_equal(parsed.actions[0], np.array(values, dtype=float))
        assert (parsed.reason[0] == "") == (status == "ok")


def test_corpus_is_large_and_covers_every_outcome():
    assert len(CASES) >= 120
    assert len({c[0] for c in CASES}) == len(CASES)
    assert {c[2] for c in CASES} == {"ok", "corrected", "failed"}
    assert {c[4] for c in CASES} == {"", "format", "truncated", "implausible", "ambiguous"}
    assert set(HISTORIES) <= {c[0] for c in CASES}


def test_corpus_reasons_say_what_happened():
    by_name = {c[0]: c for c in CASES}

    def reason(name):
        return lightemma.parse_actions(by_name[name][1], history=_history(name)).reason[0]

    assert "skipped 1 list(s) repeating the history given in the prompt (at position 14)" in reason(
        "quoted-history-before"
    )
    assert "skipped 1 list(s) repeating the history" in reason("recap-history-after")
    assert "the list equals the history given in the prompt (no other list)" in reason("history-only")
    assert 'took the list after the cue "actually" at position' in reason("self-correction-three")
    assert "the same list given 2 times" in reason("repeated-same-list")
    assert reason("recap-after-answer") == (
        "ambiguous: 2 different lists of 6 actions (at positions 0 and 116), and no correction or "
        "final-answer cue says which is the answer"
    )
    assert "ambiguous: 2 different lists" in reason("waypoints-after-answer")
    assert reason("range-in-pairs") == "pair 1 (4.5-5.0, 0.0) is ambiguous: 4.5-5.0 is a range or a subtraction"
    assert "pair 2 (5.5, 0.01-0.02) is ambiguous: 0.01-0.02" in reason("range-curvature")
    assert "12 standalone numbers, but their pairing is unknown" in reason("bare-numbers")
    assert "--0.02 has a doubled sign" in reason("doubled-minus")
    assert "by their speed / curvature labels" in reason("speeds-then-curvatures-slow")
    assert "as the columns of a table" in reason("table-columns")
    assert "a flat list of 12 numbers read as v1, c1" in reason("flat-list-gpt-4o")
    assert "pairs written as 'v c' items" in reason("space-separated-items-llama")
    assert "speeds and curvatures read from their labelled lists" in reason("speeds-and-curvatures-json")
    assert "reasoning block removed" in reason("think-block")
    assert "expression evaluated (pair 1, 2, 3, 4, 5, 6)" in reason("arithmetic-spaced")
    assert "expression evaluated (pair 1, 2, 3)" in reason("arithmetic-fraction")
    assert reason("fused-72b").startswith("pair 1 (3.7640.002) 3.7640.002 is not a number")
    assert "0001 has leading zeros" in reason("lost-decimal-points")
    assert reason("lost-decimal-no-zeros") == "speed 5254 at step 1 outside [-10, 50] m/s"
    assert reason("degrees-not-curvature") == "curvature 15 at step 1 outside [-1, 1] 1/m"
    assert reason("truncated-mid-pair").startswith("truncated")
    assert "found lists of 7 pairs" in reason("seven-pairs")
    assert "13 standalone number(s)" in reason("one-number-too-many")
    assert "12 standalone numbers" in reason("prose-horizon-labels")
    assert "pair 3 (7.0, about 0)" not in reason("stray-text-in-pair")  # a prose group is not a pair: 5 pairs remain
    assert "found lists of 5 pairs" in reason("stray-text-in-pair")


def test_batch_of_the_whole_corpus_matches_one_by_one():
    answers = [c[1] for c in CASES]
    histories = np.array([HISTORIES.get(c[0], [(0.0, 0.0)] * 6) for c in CASES], dtype=float)
    batch = lightemma.parse_actions(answers, history=histories)
    assert batch.actions.shape == (len(answers), 6, 2)
    for i, answer in enumerate(answers):
        one = lightemma.parse_actions(answer, history=histories[i : i + 1])
        assert one.status[0] == batch.status[i]
        assert one.reason[0] == batch.reason[i]
        np.testing.assert_array_equal(one.actions[0], batch.actions[i])


def test_strict_mode_fails_what_lenient_corrects():
    corrected = [c[1] for c in CASES if c[2] == "corrected"]
    assert len(corrected) >= 60
    strict = lightemma.parse_actions(corrected, mode="strict")
    assert (strict.status == "failed").all()
    assert np.isnan(strict.actions).all()


def test_n_other_than_six():
    parsed = lightemma.parse_actions("[(1, 0.1), (2, 0.2), (3, 0.3)]", n=3)
    assert parsed.status.tolist() == ["ok"]
    assert parsed.actions.shape == (1, 3, 2)
    assert lightemma.parse_actions("[(1, 0.1), (2, 0.2), (3, 0.3)]").status[0] == "failed"


def test_ok_mask_and_len():
    parsed = lightemma.parse_actions([CASES[0][1], "nothing"])
    assert len(parsed) == 2
    assert parsed.ok.tolist() == [True, False]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"texts": [1, 2]}, "item 0 is int"),
        ({"texts": ["ok", None]}, "item 1 is NoneType"),
        ({"texts": ("a", b"b")}, "item 1 is bytes"),
        ({"texts": None}, "str or an iterable of str, got NoneType"),
        ({"texts": b"[(1, 2)]"}, "got bytes"),
        ({"texts": 5}, "got int"),
        ({"texts": np.zeros(3)}, "array of str, got dtype float64"),
        ({"texts": np.array([["a"], ["b"]])}, "1-D array of str, got shape (2, 1)"),
        ({"texts": np.array(["a", 3], dtype=object)}, "item 1 is int"),
        ({"texts": "x", "n": 0}, "n must be a positive integer"),
        ({"texts": "x", "n": True}, "n must be a positive integer"),
        ({"texts": "x", "mode": "fuzzy"}, 'unknown parse mode "fuzzy"; expected one of: strict, lenient, paper, json'),
        ({"texts": "x", "mode": None}, "mode must be one of"),
        ({"texts": "x", "speed_range": (50, -10)}, "lo < hi"),
        ({"texts": "x", "speed_range": (0, float("nan"))}, "lo < hi"),
        ({"texts": "x", "speed_range": (0, float("inf"))}, "finite"),
        ({"texts": "x", "speed_range": 50}, "speed_range must be (lo, hi)"),
        ({"texts": "x", "speed_range": ("a", "b")}, "two numbers"),
        ({"texts": "x", "max_abs_curvature": 0}, "max_abs_curvature must be a finite number > 0"),
        ({"texts": "x", "max_abs_curvature": -1.0}, "max_abs_curvature must be a finite number > 0"),
        ({"texts": "x", "max_abs_curvature": "1"}, "max_abs_curvature must be a number"),
        ({"texts": "x", "max_abs_curvature": True}, "max_abs_curvature must be a number"),
    ],
)
def test_bad_arguments_raise_value_error(kwargs, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        lightemma.parse_actions(**kwargs)


EXACT = "[(5.0, 0.01), (5.5, 0.0), (6.0, -0.02), (6.5, 0.0), (7.0, 0.0), (7.5, 0.003)]"


def test_texts_may_be_any_iterable_or_a_numpy_array_of_str():
    want = lightemma.parse_actions([EXACT, "nope"])
    for texts in (
        (EXACT, "nope"),
        iter([EXACT, "nope"]),
        np.array([EXACT, "nope"]),
        np.array([EXACT, "nope"], dtype=object),
        {EXACT: 1, "nope": 2}.keys(),
        [np.str_(EXACT), "nope"],
    ):
        got = lightemma.parse_actions(texts)
        assert got.status.tolist() == want.status.tolist() == ["ok", "failed"]
        np.testing.assert_array_equal(got.actions, want.actions)


def test_lone_surrogates_do_not_raise():
    parsed = lightemma.parse_actions(["\ud800" + EXACT, "\udfff"])
    assert parsed.status.tolist() == ["corrected", "failed"]


def test_failure_kinds():
    parsed = lightemma.parse_actions(
        [EXACT, "", "no actions here", EXACT.replace("7.5", "75.0"), EXACT.replace("nan", "x").replace("0.003", "nan")]
    )
    assert parsed.failure.tolist() == ["", "format", "format", "implausible", "format"]
    assert parsed.reason[3] == "speed 75 at step 6 outside [-10, 50] m/s"
    assert parsed.failure.dtype.kind == "U" and parsed.status.dtype.kind == "U"


def test_plausibility_limits_are_options():
    fast = EXACT.replace("7.5", "60.0")
    sharp = EXACT.replace("-0.02", "-1.5")
    assert lightemma.parse_actions([fast, sharp]).failure.tolist() == ["implausible", "implausible"]
    assert lightemma.parse_actions(sharp).reason[0] == "curvature -1.5 at step 3 outside [-1, 1] 1/m"
    off = lightemma.parse_actions([fast, sharp], speed_range=None, max_abs_curvature=None)
    assert off.status.tolist() == ["ok", "ok"]
    assert off.actions[0, 5, 0] == 60.0 and off.actions[1, 2, 1] == -1.5
    # limits are inclusive, and can be tightened
    assert lightemma.parse_actions(fast, speed_range=(0, 60)).status[0] == "ok"
    assert lightemma.parse_actions(EXACT, speed_range=(0, 7)).reason[0] == "speed 7.5 at step 6 outside [0, 7] m/s"
    assert lightemma.parse_actions(EXACT, max_abs_curvature=0.01).failure[0] == "implausible"
    # the gate applies in strict and json modes too, never in paper mode
    assert lightemma.parse_actions(fast, mode="strict").failure[0] == "implausible"
    assert lightemma.parse_actions(fast, mode="paper").status[0] == "ok"


def test_plausibility_record():
    from lightemma.actions import plausibility

    assert plausibility() == {"speed_range": [-10.0, 50.0], "max_abs_curvature": 1.0}
    assert plausibility(None, None) == {"speed_range": None, "max_abs_curvature": None}
    assert plausibility((0, 30), 0.5) == {"speed_range": [0.0, 30.0], "max_abs_curvature": 0.5}
    with pytest.raises(ValueError, match="lo < hi"):
        plausibility((5, 5))


def test_json_mode():
    obj = '{"actions": [[5.0, 0.01], [5.5, 0.0], [6.0, -0.02], [6.5, 0.0], [7.0, 0.0], [7.5, 0.003]]}'
    parsed = lightemma.parse_actions(
        [obj, "```json\n" + obj + "\n```", obj[:-10], EXACT, obj.replace("5.5", "+5.5")], mode="json"
    )
    assert parsed.status.tolist() == ["ok", "ok", "failed", "failed", "failed"]
    assert parsed.failure.tolist() == ["", "", "truncated", "format", "format"]
    np.testing.assert_array_equal(parsed.actions[0], lightemma.parse_actions(EXACT).actions[0])


def test_empty_batch():
    parsed = lightemma.parse_actions([])
    assert parsed.actions.shape == (0, 6, 2)
    assert len(parsed) == 0


def test_hostile_inputs_finish_and_fail_cleanly():
    hostile = [
        "9" * 1_000_000,
        "[" * 200_000 + "]" * 200_000,
        "(" * 100_000,
        bytes(range(256)).decode("latin-1") * 100,
        "\x00\ufffd\u202e" * 1000,
        "-" * 100_000 + "1",
        "1e" + "9" * 10_000,
        "3." + "0.0" * 100_000,
        "<think>" * 50_000,
        "</think>" * 50_000 + "[(1, 0.2)]" * 10_000,
        ", ".join(["(1, 0.2)"] * 100_000),  # far more pairs than a list of six: never guessed
    ]
    for mode in ("lenient", "strict", "paper", "json"):
        parsed = lightemma.parse_actions(hostile, mode=mode)
        if mode == "paper":  # digit runs are numbers wherever they are
            assert parsed.status.tolist() == [paper_reference(t)[0] for t in hostile]
        else:
            assert parsed.status.tolist() == ["failed"] * len(hostile), mode
            assert parsed.failure[2] == ("truncated" if mode == "lenient" else "format")
    assert all(len(r) < 300 for r in lightemma.parse_actions(hostile).reason)
    assert lightemma.parse_actions("(" * 100_000 + "1").failure[0] == "truncated"
    assert lightemma.parse_actions("[" * 100_000 + "(see").failure[0] == "format"


finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(finite, finite), min_size=6, max_size=6))
def test_round_trip_of_the_exact_format(pairs):
    text = "[" + ", ".join(f"({v!r}, {c!r})" for v, c in pairs) + "]"
    parsed = lightemma.parse_actions(text, mode="strict", speed_range=None, max_abs_curvature=None)
    assert parsed.status[0] == "ok", parsed.reason[0]
    np.testing.assert_array_equal(parsed.actions[0], np.array(pairs))
    # with the default limits: failed as implausible exactly when a value is outside them
    gated = lightemma.parse_actions(text, mode="strict")
    outside = any(not -10 <= v <= 50 or abs(c) > 1 for v, c in pairs)
    assert gated.failure[0] == ("implausible" if outside else ""), gated.reason[0]


speed = st.floats(min_value=-10, max_value=50, allow_nan=False).map(lambda x: round(x, 3))
curvature = st.floats(min_value=-1, max_value=1, allow_nan=False).map(lambda x: round(x, 4))
plausible_pairs = st.lists(st.tuples(speed, curvature), min_size=6, max_size=6)


def _fmt(x: float, style: int) -> str:
    return (repr(x), f"{x:.4f}", f"{x:e}", repr(x).replace("-", "\u2212"))[style]


@st.composite
def a_list(draw, pairs=plausible_pairs):
    """A valid list of six pairs in one of the shapes models write."""
    values = draw(pairs)
    style = draw(st.integers(0, 3))
    inner = draw(st.sampled_from(["()", "[]"]))
    outer = draw(st.sampled_from(["[]", "[]", "()"]))
    sep = draw(st.sampled_from([", ", ",", ",\n  ", " ", "; "]))
    pair_sep = draw(st.sampled_from([", ", ",", " ; "]))
    body = sep.join(f"{inner[0]}{_fmt(v, style)}{pair_sep}{_fmt(c, style)}{inner[1]}" for v, c in values)
    return outer[0] + body + outer[1], values


WORDS = st.sampled_from(
    [
        "the",
        "car",
        "Past actions:",
        "So:",
        "Wait,",
        "history",
        "speed",
        "is",
        "3 seconds",
        "0.5 s",
        "v1 =",
        "6 steps",
        "at",
        "about",
        "m/s",
        "-",
        "—",
        ".",
        ",",
        ":",
        "**",
        "```",
        "\n",
        "\n\n",
        "I think",
        "e.g.",
    ]
)
any_number = st.floats(min_value=-1e4, max_value=1e4, allow_nan=False).map(lambda x: repr(round(x, 3)))


@st.composite
def prose_with_pairs(draw, full_lists=False):
    """Prose holding other bracketed number pairs: single pairs, short and long lists, reasoning blocks
    (and, with ``full_lists``, other complete lists of six pairs)."""
    parts = []
    for _ in range(draw(st.integers(0, 8))):
        kind = draw(st.integers(0, 6))
        if kind == 0:
            parts.append(draw(any_number))
        elif kind == 1:
            parts.append(f"({draw(any_number)}, {draw(any_number)}) and")  # six in a row would be a list
        elif kind == 2:
            k = draw(st.sampled_from([1, 2, 3, 4, 5, 7, 8]))
            parts.append("[" + ", ".join(f"({draw(any_number)}, {draw(any_number)})" for _ in range(k)) + "]")
        elif kind == 3 and full_lists:
            parts.append(
                draw(a_list(st.lists(st.tuples(any_number.map(float), any_number.map(float)), min_size=6, max_size=6)))[
                    0
                ]
            )
        elif kind == 4:
            parts.append("<think>" + draw(a_list())[0] + " (5, [1, 2" + "</think>")  # anything goes inside
        else:
            parts.append(draw(WORDS))
    return " ".join(parts)


@settings(max_examples=600, deadline=None)
@given(prose_with_pairs(), a_list(), st.lists(WORDS | any_number, max_size=6).map(" ".join))
def test_the_one_list_among_prose_with_other_pairs_is_returned(before, answer, after):
    text, values = answer
    parsed = lightemma.parse_actions(before + "\n" + text + "\n" + after)
    assert parsed.status[0] in ("ok", "corrected"), parsed.reason[0]
    np.testing.assert_array_equal(parsed.actions[0], np.array(values))


NO_CUE_WORDS = st.sampled_from(
    [
        "the",
        "car",
        "Past actions:",
        "So:",
        "history",
        "For comparison,",
        "Alternatively,",
        "speed",
        "is",
        "3 seconds",
        "at",
        "about",
        "\n",
        "\n\n",
        "I think",
        "e.g.",
        "**",
        "Also",
        "then",
        "final speed",
        "the correct",
        "waypoints:",
        "m/s",
        ".",
        "we could wait for",
        "if it is actually red",
        "the updated plan",
    ]
)
CUES = st.sampled_from(
    [
        "Wait,",
        "Correction:",
        "Final answer:",
        "**Final Answer:**",
        "Actually,",
        "Revised:",
        "Corrected:",
        "wait,",
        "the final answer is",
    ]
)


@settings(max_examples=600, deadline=None)
@given(
    a_list(),
    a_list(),
    st.lists(NO_CUE_WORDS, max_size=5).map(" ".join),
    st.none() | CUES,
    st.sampled_from(["none", "b", "other"]),
    prose_with_pairs(full_lists=True),
)
def test_a_later_different_list_never_wins_without_a_cue(first, second, between, cue, history_is, after):
    """Issue 19: for a valid answer A followed by a different list B, lenient never returns B unless a cue
    introduces B. Issue 32: a B equal to the given history is skipped only where its sentence calls it the past
    (a past word before it, no sentence end between); otherwise it is a candidate like any other, and a cue
    introducing it wins (with a past word in the same sentence too, it is ambiguous)."""
    (text_a, a), (text_b, b) = first, second
    a, b = np.array(a, dtype=float), np.array(b, dtype=float)
    assume(not np.array_equal(a, b))
    history = {"none": None, "b": b, "other": np.full((6, 2), 0.123)}[history_is]
    text = f"{text_a} {between} {cue or ''} {text_b}"
    parsed = lightemma.parse_actions(text, history=None if history is None else history[None])
    got = parsed.actions[0]
    last_past = max(between.rfind("Past"), between.rfind("history"))
    called_past = history_is == "b" and last_past >= 0 and "." not in between[last_past:]
    if cue is None:
        assert not np.array_equal(got, b), (text, parsed.reason[0])
        if called_past:  # B is a quotation: A is the answer
            np.testing.assert_array_equal(got, a)
        else:
            assert parsed.failure[0] == "ambiguous", (text, parsed.reason[0])
    elif called_past:  # the cue and the past word disagree about B
        assert parsed.failure[0] == "ambiguous" and "introduced both as the past" in parsed.reason[0], (
            text,
            parsed.reason[0],
        )
    else:  # the cue introduces B, even when B equals the history
        np.testing.assert_array_equal(got, b)
    # whatever follows, a text with A and B never gives B without a cue
    tail = lightemma.parse_actions(f"{text} {after}", history=None if history is None else history[None])
    if cue is None:
        assert not np.array_equal(tail.actions[0], b), (text, after, tail.reason[0])


@settings(max_examples=400, deadline=None)
@given(prose_with_pairs(), a_list(), st.data())
def test_a_cut_off_list_never_gives_actions(before, answer, data):
    text, _ = answer
    cut = data.draw(st.integers(1, len(text) - 1))
    parsed = lightemma.parse_actions(before + "\n" + text[:cut])
    assert parsed.status[0] == "failed", (text[:cut], parsed.reason[0])
    assert np.isnan(parsed.actions[0]).all()


FRAGMENTS = st.sampled_from(
    [
        "(",
        ")",
        "[",
        "]",
        "{",
        "}",
        ",",
        ";",
        " ",
        "\n",
        "-",
        "+",
        "*",
        "/",
        ".",
        "\u2212",
        "e",
        "0",
        "1",
        "5.0",
        "0.01",
        "0001",
        "3.7640.002",
        "nan",
        "<think>",
        "</think>",
        "v1 =",
        "m/s",
        "1/m",
        '"v": ',
        '"c": ',
        "3 seconds",
        "1. ",
        "1) ",
        "\x00",
        "κ",
    ]
)


@settings(max_examples=1500, deadline=None)
@given(
    st.text(max_size=400)
    | st.binary(max_size=400).map(lambda b: b.decode("utf-8", "replace"))
    | st.lists(FRAGMENTS, max_size=80).map("".join)
)
def test_fuzz_arbitrary_text_never_raises(text):
    for mode in ("lenient", "strict", "json", "paper"):
        parsed = lightemma.parse_actions([text, text], mode=mode)
        status, failure = parsed.status[0], parsed.failure[0]
        assert (status, failure, parsed.reason[0]) == (parsed.status[1], parsed.failure[1], parsed.reason[1])
        assert status in ("ok", "corrected", "failed")
        assert (failure == "") == (status != "failed")
        assert (parsed.reason[0] == "") == (status == "ok")
        if status == "failed":
            assert np.isnan(parsed.actions[0]).all()
        else:
            values = parsed.actions[0]
            assert np.isfinite(values).all()
            if mode != "paper":
                assert ((values[:, 0] >= -10) & (values[:, 0] <= 50)).all() and (np.abs(values[:, 1]) <= 1).all()
