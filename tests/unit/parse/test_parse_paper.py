"""``mode="paper"``: the paper's own FE / FE corr rules, checked against a plain-Python restatement.

The restatement below is the paper's two rules written the obvious way (``ast.literal_eval``
plus a regular expression); the Rust core must agree with it on realistic and nasty texts.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import lightemma
from tests.support.paper_reference import paper_reference


def check_agrees(texts: list[str], n: int = 6) -> None:
    parsed = lightemma.parse_actions(texts, n=n, mode="paper")
    for i, text in enumerate(texts):
        status, values = paper_reference(text, n)
        assert parsed.status[i] == status, (text, parsed.reason[i])
        if values is None:
            assert np.isnan(parsed.actions[i]).all()
            assert parsed.failure[i] == "format" and parsed.reason[i]
        else:
            got = parsed.actions[i].ravel()
            np.testing.assert_array_equal(got, values, err_msg=repr(text))
            # the sign of zero too: Python's `-0` is the int 0, `-0.0` is negative
            assert [math.copysign(1, v) for v in got] == [math.copysign(1, v) for v in values], text
            assert parsed.failure[i] == ""
            assert (parsed.reason[i] == "") == (status == "ok")


SIX = [(5.0, 0.01), (5.5, 0.0), (6.0, -0.02), (6.5, 0.0), (7.0, 0.0), (7.5, 0.003)]
EXACT = "[" + ", ".join(f"({v}, {c})" for v, c in SIX) + "]"


# ---------------------------------------------------------------- the issue's seven kinds
@pytest.mark.parametrize(
    ("name", "text", "status"),
    [
        ("exact", EXACT, "ok"),
        ("list-of-lists", "[" + ", ".join(f"[{v}, {c}]" for v, c in SIX) + "]", "corrected"),
        ("prose-around", "Sure! " + EXACT + " Drive safely.", "corrected"),
        ("think-block", "<think>history [(3.0, 0.0)]</think>\n" + EXACT, "corrected"),  # 2 + 12 runs: first 12
        ("self-correction", EXACT + " Wait, corrected: " + EXACT, "corrected"),
        (
            "prose-numbers",
            "Over the next 3 seconds at 0.5 s steps: v1 = 3.0, c1 = 0.0, v2 = 3.1, c2 = 0.0, v3 = 3.2",
            "corrected",
        ),
        ("arithmetic", "[" + ", ".join(["(7.2-0.5, 0.002)"] * 6) + "]", "failed"),  # `7.2-0.5` is no run of the form
        ("fused", "[" + "".join(["(3.7640.002)"] * 6) + "]", "failed"),
        (
            "lost-decimal-points",
            "[(5254,0001),(5559,00005),(5864,0001),(6170,0001),(6475,0001),(6780,0001)]",
            "corrected",
        ),
        (
            "truncated",
            "[(5.0, 0.0), (5.1, 0.0), (5.2, 0.0), (5.3, 0.0), (5.5, 0.0), (5.6, -0.0",
            "corrected",
        ),  # c6 = -0.0
        ("empty", "", "failed"),
    ],
)
def test_paper_mode_on_the_issue_kinds(name, text, status):
    parsed = lightemma.parse_actions(text, mode="paper")
    assert parsed.status[0] == status, parsed.reason[0]
    check_agrees([text])


def test_paper_mode_reads_what_the_paper_read():
    # the paper's corrections: `0001` is a Python syntax error (FE) but gives 1.0 as a digit run
    lost = lightemma.parse_actions(
        "[(5254,0001),(5559,00005),(5864,0001),(6170,0001),(6475,0001),(6780,0001)]", mode="paper"
    )
    assert lost.actions[0, 0].tolist() == [5254.0, 1.0]
    assert "leading zeros" in lost.reason[0]
    # no plausibility gate in paper mode, even with the limits given
    assert lightemma.parse_actions(EXACT.replace("5.0", "5254"), mode="paper", speed_range=(-10, 50)).status[0] == "ok"
    # prose numbers are read as the paper read them: `3` seconds, `0.5` s, `1` of v1 …
    prose = lightemma.parse_actions(
        "Over the next 3 seconds at 0.5 s steps: v1 = 3.0, c1 = 0.0, v2 = 3.1, c2 = 0.0, v3 = 3.2", mode="paper"
    )
    assert prose.actions[0, :2].tolist() == [[3.0, 0.5], [1.0, 3.0]]


def test_paper_mode_non_finite_fails():
    too_big = "[" + ", ".join(["(" + "9" * 400 + ", 0)"] + ["(1, 0)"] * 5) + "]"
    parsed = lightemma.parse_actions([too_big, EXACT.replace("7.5", "1e999")], mode="paper")
    assert parsed.status.tolist() == ["failed", "failed"]
    assert all("non-finite" in r for r in parsed.reason)
    check_agrees([too_big])


def test_paper_mode_n_other_than_six():
    three = "[(1, 0.1), (2, 0.2), (3, 0.3)]"
    assert lightemma.parse_actions(three, n=3, mode="paper").status[0] == "ok"
    check_agrees([three, EXACT], n=3)


# ---------------------------------------------------------------- the property
def _number_texts() -> st.SearchStrategy[str]:
    finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)
    fixed = st.sampled_from(
        [
            "5.",
            ".5",
            "1e3",
            "1E-3",
            "2.5e+2",
            "0001",
            "00",
            "0.0",
            "-0",
            "-0.0",
            "1_000",
            "1__0",
            "0x1f",
            "0b101",
            "0o17",
            "\u22125",
            "5a",
            "1.5.5",
            "inf",
            "nan",
            "1e999",
            "True",
            "1j",
            "--5",
            "-(5)",
            "(5)",
            "((5))",
            "+ 5",
            "7.2-0.5",
            "1/50",
            "3.7640.002",
            "0_0",
            "09.5",
            "1e",
            "- (0)",
            "12345678901234567890123",
        ]
    )
    valid = st.one_of(
        st.integers(-(10**6), 10**6).map(str),
        finite.map(repr),
        finite.map(lambda x: f"{x:.3f}"),
        finite.map(lambda x: f"{x:e}"),
        st.integers(0, 99).map(lambda x: "+" + str(x)),
    )
    # one number in ~15 is one of the nasty forms, so that whole lists are often valid
    return st.integers(0, 14).flatmap(lambda k: fixed if k == 0 else valid)


def _pair_texts(number: st.SearchStrategy[str]) -> st.SearchStrategy[str]:
    def build(a, b, style):
        return {
            "round": f"({a}, {b})",
            "tight": f"({a},{b})",
            "square": f"[{a}, {b}]",
            "trailing": f"({a}, {b},)",
            "wrapped": f"(({a}, {b}))",
            "inner": f"(({a}), {b})",
            "three": f"({a}, {b}, {a})",
            "one": f"({a})",
            "no-comma": f"({a} {b})",
            "semicolon": f"({a}; {b})",
            "newlines": f"(\n  {a},\n  {b}\n)",
            "comment": f"({a},  # speed\n {b})",
        }[style]

    valid = ["round"] * 30 + ["tight", "trailing", "wrapped", "inner", "newlines", "comment"] * 2
    styles = st.sampled_from(valid + ["square", "three", "one", "no-comma", "semicolon"])
    return st.builds(build, number, number, styles)


def _list_texts() -> st.SearchStrategy[str]:
    number = _number_texts()
    pairs = st.lists(_pair_texts(number), min_size=0, max_size=8)
    six_pairs = st.lists(_pair_texts(number), min_size=6, max_size=6)

    def build(ps, sep, close, trailing, outer):
        body = sep.join(ps) + ("," if trailing else "")
        text = "[" + body + close
        return "(" + text + ")" if outer else text

    return st.builds(
        build,
        st.one_of(six_pairs, six_pairs, pairs),
        st.sampled_from([", ", ",", ",\n  ", " , ", ",\t", " "]),
        st.sampled_from(["]"] * 8 + ["", ")"]),
        st.booleans(),
        st.sampled_from([False] * 5 + [True]),
    )


PROSE = st.lists(
    st.sampled_from(
        list("abcdefv κ:=,.;-()[]#\n\t 0123456789−'\"<>/*")
        + ["<think>", "</think>", "```", "3 seconds", "0.5 s", "v1 = "]
    ),
    max_size=20,
).map("".join)
WHITE = st.sampled_from(["\n", "  ", "\t", "\n\n", " # done", "# note\n", "\n  ", "\n\x0c", "\r\n", "\n \n"])
AROUND = st.one_of(st.just(""), WHITE, WHITE, PROSE)


@settings(max_examples=1500, deadline=None)
@given(before=AROUND, body=_list_texts(), after=AROUND)
def test_paper_mode_agrees_with_the_python_restatement(before, body, after):
    check_agrees([before + body + after])


@settings(max_examples=500, deadline=None)
@given(st.text(max_size=200) | st.binary(max_size=200).map(lambda b: b.decode("utf-8", "replace")))
def test_paper_mode_agrees_on_arbitrary_text(text):
    check_agrees([text.replace("\\", "")])  # a backslash at the top level: see docs/parsing.md
