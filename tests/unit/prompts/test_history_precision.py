"""Histories given in float32 (a custom frame set) are written into prompts as the numbers they hold in float32, with
no widening noise: ``4.512``, not ``4.51200008392334``."""

from __future__ import annotations

import numpy as np
import pytest

from lightemma.frames import history_placeholders
from lightemma.frames.render import format_history
from lightemma.prompts import load_prompt_set

HISTORY = [[4.512, 0.012], [4.6, -0.0], [5.0, 1e-05], [5.25, -0.0031], [6.1, 0.0], [7.3, 0.2]]


@pytest.mark.parametrize("dtype", [np.float32, np.float16])
def test_a_narrow_float_history_prints_the_shortest_decimal_of_its_own_precision(dtype):
    narrow = np.asarray(HISTORY, dtype=dtype)
    got = history_placeholders(narrow)
    expected = [[float(str(v)) for v in row] for row in narrow]  # e.g. np.float32(4.512) prints 4.512
    assert got == history_placeholders(expected)  # as if the same decimals had been given in float64
    assert format_history(narrow) == got["history"]
    for value in ("4.51200008392334", "0.012000000104308128", "4.51171875"):  # float32 / float16 widened to float64
        assert value not in "".join(got.values())
    if dtype is np.float32:
        assert got["history"] == history_placeholders(HISTORY)["history"]  # these decimals survive float32 exactly
        assert got["speeds"] == "[4.512, 4.6, 5.0, 5.25, 6.1, 7.3]"
        assert got["curvatures"] == "[0.012, -0.0, 1e-05, -0.0031, 0.0, 0.2]"
    # float32 scalars in plain lists, as a hand-made frame may hold them
    rows = [[dtype(v), dtype(c)] for v, c in HISTORY]
    assert history_placeholders(rows) == got


def test_a_float64_history_is_written_as_before():
    history = np.asarray(HISTORY)
    assert history_placeholders(history)["history"] == (
        "[(4.512, 0.012), (4.6, 0.0), (5.0, 0.00001), (5.25, -0.0031), (6.1, 0.0), (7.3, 0.2)]"
    )
    assert history_placeholders(history)["speeds"] == "[4.512, 4.6, 5.0, 5.25, 6.1, 7.3]"
    assert history_placeholders([[1.0, 0], [2.0, 0]])["curvatures"] == "[0, 0]"  # an int stays an int (the reference's)
    wide = np.float32(4.512).astype(np.float64)  # a float64 that came from float32 is a float64: written in full
    assert format_history([[wide, 0.0]]) == f"[({float(wide)!r}, 0.0)]"


def test_the_prompt_of_a_float32_history_has_no_widening_noise():
    history = history_placeholders(np.asarray(HISTORY, np.float32))
    prompt = load_prompt_set().render("intent", scene="A road.", **history)
    assert "4.512" in prompt and "4.51200008392334" not in prompt and "0.012000000104308128" not in prompt


def test_a_history_that_is_not_pairs_is_refused():
    with pytest.raises(ValueError, match=r"shape \(T, 2\)"):
        history_placeholders(np.zeros(6, dtype=np.float32))
    with pytest.raises(ValueError, match=r"shape \(T, 2\)"):
        history_placeholders([[1.0, 2.0, 3.0]])
