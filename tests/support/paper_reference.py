"""The paper's FE / FE corr rules restated in plain Python (``ast.literal_eval`` + a regular expression).

``mode="paper"`` of the Rust core must agree with this on any text (tests/unit/parse/test_parse_paper.py).
"""

from __future__ import annotations

import ast
import math
import re
import warnings

RUN = re.compile(r"[0-9.\-]+")
PLAIN = re.compile(r"-?[0-9]+(\.[0-9]+)?")


def paper_reference(text: str, n: int = 6) -> tuple[str, list[float] | None]:
    """The paper's rules in plain Python: (status, 2n values or None)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # e.g. SyntaxWarning for `5if`
            value = ast.literal_eval(text)
    except Exception:  # noqa: BLE001 - any failure to read the literal is FE
        value = None
    number = lambda x: type(x) in (int, float)  # noqa: E731 - not bool, not complex
    if (
        isinstance(value, list)
        and len(value) == n
        and all(isinstance(p, tuple) and len(p) == 2 and all(number(x) for x in p) for p in value)
    ):
        status, raw = "ok", [x for p in value for x in p]
    else:
        runs = [r for r in RUN.findall(text) if PLAIN.fullmatch(r)]
        if len(runs) < 2 * n:
            return "failed", None
        status, raw = "corrected", runs[: 2 * n]
    try:
        values = [float(x) for x in raw]
    except OverflowError:  # an int too large for a float
        return "failed", None
    if not all(math.isfinite(v) for v in values):
        return "failed", None
    return status, values
