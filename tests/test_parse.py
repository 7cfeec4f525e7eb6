"""The answer parser: a corpus of realistic answers, fuzzing, and the public API's contract."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import lightemma
from parse_corpus import CASES


@pytest.mark.parametrize(("name", "answer", "status", "values"), CASES, ids=[c[0] for c in CASES])
def test_corpus(name, answer, status, values):
    parsed = lightemma.parse_actions(answer)
    assert parsed.status[0] == status, parsed.reason[0]
    if values is None:
        assert np.isnan(parsed.actions[0]).all()
        assert parsed.reason[0]
    else:
        np.testing.assert_array_equal(parsed.actions[0], np.array(values, dtype=float))
        assert (parsed.reason[0] == "") == (status == "ok")


def test_corpus_is_large_and_covers_every_status():
    assert len(CASES) >= 60
    assert {c[2] for c in CASES} == {"ok", "corrected", "failed"}


def test_batch_of_the_whole_corpus_matches_one_by_one():
    answers = [c[1] for c in CASES]
    batch = lightemma.parse_actions(answers)
    assert batch.actions.shape == (len(answers), 6, 2)
    for i, answer in enumerate(answers):
        one = lightemma.parse_actions(answer)
        assert one.status[0] == batch.status[i]
        assert one.reason[0] == batch.reason[i]
        np.testing.assert_array_equal(one.actions[0], batch.actions[i])


def test_strict_mode_fails_what_lenient_corrects():
    corrected = [c[1] for c in CASES if c[2] == "corrected"]
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
        ({"texts": None}, "str or a sequence of str"),
        ({"texts": "x", "n": 0}, "n must be a positive integer"),
        ({"texts": "x", "mode": "fuzzy"}, "unknown parse mode \"fuzzy\"; expected one of: strict, lenient"),
    ],
)
def test_bad_arguments_raise_value_error(kwargs, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        lightemma.parse_actions(**kwargs)


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
        ", ".join(["(1, 2)"] * 100_000),  # far more pairs than needed: the first six are taken
    ]
    parsed = lightemma.parse_actions(hostile)
    assert parsed.status[:-1].tolist() == ["failed"] * (len(hostile) - 1)
    assert parsed.status[-1] == "corrected"
    np.testing.assert_array_equal(parsed.actions[-1], np.tile([1.0, 2.0], (6, 1)))


finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(finite, finite), min_size=6, max_size=6))
def test_round_trip_of_the_exact_format(pairs):
    text = "[" + ", ".join(f"({v!r}, {c!r})" for v, c in pairs) + "]"
    parsed = lightemma.parse_actions(text, mode="strict")
    assert parsed.status[0] == "ok", parsed.reason[0]
    np.testing.assert_array_equal(parsed.actions[0], np.array(pairs))


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(finite, finite), min_size=6, max_size=6), st.text(max_size=40), st.text(max_size=40))
def test_pairs_survive_prose_around_them(pairs, before, after):
    # prose that cannot itself contain brackets or numbers
    clean = str.maketrans("", "", "()[]0123456789.-+\u2212eEnNiIfF")
    before, after = before.translate(clean), after.translate(clean)
    text = before + " [" + ", ".join(f"({v!r}, {c!r})" for v, c in pairs) + "] " + after
    parsed = lightemma.parse_actions(text)
    assert parsed.status[0] in ("ok", "corrected")
    np.testing.assert_array_equal(parsed.actions[0], np.array(pairs))


@settings(max_examples=1000, deadline=None)
@given(st.text(max_size=400) | st.binary(max_size=400).map(lambda b: b.decode("utf-8", "replace")))
def test_fuzz_arbitrary_text_never_raises(text):
    parsed = lightemma.parse_actions([text, text])
    status = parsed.status[0]
    assert status in ("ok", "corrected", "failed")
    assert parsed.status[1] == status
    if status == "failed":
        assert np.isnan(parsed.actions[0]).all() and parsed.reason[0]
    else:
        assert all(math.isfinite(x) for x in parsed.actions[0].ravel())
