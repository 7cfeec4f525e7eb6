"""One frame record, one line: orjson's encoding means exactly what the standard library's would."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from lightemma.runs.records import bounded_values, loads_bounded
from lightemma.runs.store import _sanitize, _to_jsonable, encode_line


def reference(record):
    """The record as the standard library writes it (non-finite floats as null, NumPy as plain values), what the readers
    refuse as null: integers of more than 18 digits, counts, times and costs beyond their bounds (lightemma.runs.records)."""
    return json.dumps(_sanitize(bounded_values(record), []), default=_to_jsonable, allow_nan=False, ensure_ascii=False)


scalars = (
    st.floats(allow_nan=True, allow_infinity=True)
    | st.integers(-(2**70), 2**70)
    | st.booleans()
    | st.none()
    | st.text(max_size=20)
    | st.floats(width=32).map(np.float32)
    | st.integers(-5, 5).map(np.int64)
    | st.just(Path("/tmp/x.jpg"))
)
values = st.recursive(
    scalars,
    lambda inner: (
        st.lists(inner, max_size=4) | st.tuples(inner, inner) | st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=25,
)


@settings(max_examples=400, deadline=None)
@given(st.dictionaries(st.text(max_size=8), values, max_size=6))
def test_a_line_decodes_to_what_the_standard_encoding_decodes_to(record):
    line = encode_line(record)
    assert line.endswith(b"\n") and line.count(b"\n") == 1  # one whole line
    assert json.loads(line) == json.loads(reference(record))
    loads_bounded(line)  # never a line the readers refuse


def test_non_finite_numbers_become_null_and_numpy_values_plain_ones():
    record = {
        "a": [math.nan, math.inf, -math.inf, 1.5],
        "b": np.array([[0.1, np.nan]], dtype=np.float32),
        "c": np.float32(0.1),
        "d": np.int64(7),
        "e": (1, 2),
        "f": Path("x/y"),
    }
    assert json.loads(encode_line(record)) == {
        "a": [None, None, None, 1.5],
        "b": [[float(np.float32(0.1)), None]],
        "c": float(np.float32(0.1)),
        "d": 7,
        "e": [1, 2],
        "f": "x/y",
    }


def test_what_orjson_refuses_is_written_by_json_with_the_same_meaning():
    big = {"tokens": 10**30, "n": math.nan, 3: "int key", "half an emoji": "a\ud83db"}
    line = encode_line(big)
    # an integer the readers refuse (more than 18 digits) is written as unknown
    assert line.isascii() and json.loads(line) == {
        "tokens": None,
        "n": None,
        "3": "int key",
        "half an emoji": "a\ud83db",
    }
