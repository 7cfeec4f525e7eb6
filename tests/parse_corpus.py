"""Realistic stage-3 answers with the status and actions the parser must give.

Each case: (name, answer, expected status, expected 6×2 values or None).
"""

from __future__ import annotations

import json

A = [(5.0, 0.01), (5.5, 0.0), (6.0, -0.02), (6.5, 0.0), (7.0, 0.0), (7.5, 0.003)]
B = [(0.0, 0.0), (0.0, 0.0), (0.5, 0.0), (1.2, 0.0), (2.0, 0.0), (2.8, 0.0)]
C = [(3.2, 0.12), (3.0, 0.15), (2.8, 0.18), (2.8, 0.18), (3.0, 0.15), (3.2, 0.1)]
D = [(6.0, -0.001), (5.0, -0.001), (4.0, 0.0), (3.5, 0.0), (3.0, 0.0), (3.0, 0.0)]


def bracket(values, inner="()", sep=", ", pair_sep=", "):
    return "[" + sep.join(f"{inner[0]}{v}{pair_sep}{c}{inner[1]}" for v, c in values) + "]"


def lines(values, fmt):
    return "\n".join(fmt.format(i=i + 1, v=v, c=c) for i, (v, c) in enumerate(values))


CASES: list[tuple[str, str, str, list | None]] = [
    # --- strict: exactly the requested format
    ("exact", bracket(A), "ok", A),
    ("exact-stopped", bracket(B), "ok", B),
    ("exact-left-turn", bracket(C), "ok", C),
    ("exact-paper-example", "[(6.0, -0.001), (5.0, -0.001), (4.0, 0.0), (3.5, 0.0), (3.0, 0.0), (3.0, 0.0)]", "ok", D),
    ("exact-no-spaces", bracket(A, sep=",", pair_sep=","), "ok", A),
    ("exact-square-pairs", bracket(A, inner="[]"), "ok", A),
    ("exact-surrounding-whitespace", "\n\n  " + bracket(A) + "  \n", "ok", A),
    ("exact-integers", "[(5, 0), (5, 0), (6, 0), (6, 0), (7, 0), (7, 0)]", "ok", [(5, 0), (5, 0), (6, 0), (6, 0), (7, 0), (7, 0)]),
    ("exact-exponents", "[(5e0, 1e-2), (5.5, 0), (6, -2e-2), (6.5, 0), (7, 0), (7.5, 3E-3)]", "ok", A),
    ("exact-plus-signs", "[(+5.0, +0.01), (5.5, 0.0), (6.0, -0.02), (6.5, 0.0), (7.0, 0.0), (7.5, 0.003)]", "ok", A),
    ("exact-leading-dot", "[(5.0, .01), (5.5, 0.0), (6.0, -.02), (6.5, 0.0), (7.0, 0.0), (7.5, .003)]", "ok", A),
    ("exact-multiline", "[\n  (5.0, 0.01),\n  (5.5, 0.0),\n  (6.0, -0.02),\n  (6.5, 0.0),\n  (7.0, 0.0),\n  (7.5, 0.003)\n]", "ok", A),
    ("json-nested-arrays", json.dumps([list(p) for p in A]), "ok", A),
    # --- corrected: the lenient parser recovers them
    ("code-fence", "```\n" + bracket(A) + "\n```", "corrected", A),
    ("code-fence-python", "```python\n" + bracket(A) + "\n```", "corrected", A),
    ("code-fence-json", "```json\n" + json.dumps([list(p) for p in A]) + "\n```", "corrected", A),
    ("prose-before", "Here are the predicted actions: " + bracket(A), "corrected", A),
    ("prose-after", bracket(A) + "\nThese keep the vehicle in its lane.", "corrected", A),
    ("prose-both", "Based on the scene, for the next 6 steps:\n" + bracket(A) + "\nThe ego car slows slightly.", "corrected", A),
    ("trailing-period", bracket(A) + ".", "corrected", A),
    ("trailing-comma", bracket(A)[:-1] + ",]", "corrected", A),
    ("no-outer-brackets", ", ".join(f"({v}, {c})" for v, c in A), "corrected", A),
    ("missing-commas-inside", "[" + ", ".join(f"({v} {c})" for v, c in A) + "]", "corrected", A),
    ("missing-commas-between", "[" + " ".join(f"({v}, {c})" for v, c in A) + "]", "corrected", A),
    ("semicolon-pairs", "[" + "; ".join(f"({v}; {c})" for v, c in A) + "]", "corrected", A),
    ("one-pair-per-line", "\n".join(f"({v}, {c})" for v, c in A), "corrected", A),
    ("numbered-lines", lines(A, "{i}. ({v}, {c})"), "corrected", A),
    ("bulleted-lines", lines(A, "- ({v}, {c})"), "corrected", A),
    ("labels-eq", lines(A, "v{i} = {v}, c{i} = {c}"), "corrected", A),
    ("labels-colon", lines(A, "v{i}: {v}, c{i}: {c}"), "corrected", A),
    ("labels-words", lines(A, "Step {i}: speed {v}, curvature {c}"), "corrected", A),
    ("labels-kappa", lines(A, "(v{i}, κ{i}) = ({v}, {c})"), "corrected", A),
    ("labels-one-line", "; ".join(f"v{i + 1}={v} c{i + 1}={c}" for i, (v, c) in enumerate(A)), "corrected", A),
    ("time-labels", lines(A, "t+{i}: ({v}, {c})"), "corrected", A),
    ("json-objects", json.dumps([{"speed": v, "curvature": c} for v, c in A]), "corrected", A),
    ("json-object-wrapped", json.dumps({"actions": [{"v": v, "c": c} for v, c in A]}), "corrected", A),
    ("json-pretty", json.dumps({"actions": [[v, c] for v, c in A]}, indent=2), "corrected", A),
    ("unicode-minus", bracket(A).replace("-0.02", "\u22120.02"), "corrected", A),
    ("bare-numbers", " ".join(f"{v} {c}" for v, c in A), "corrected", A),
    ("comma-numbers", ", ".join(f"{v}, {c}" for v, c in A), "corrected", A),
    ("markdown-bold", "**Actions:** " + bracket(A), "corrected", A),
    ("quoted-list", '"' + bracket(A) + '"', "corrected", A),
    ("python-assignment", "actions = " + bracket(A), "corrected", A),
    ("mismatched-inner-brackets", "[" + ", ".join(f"({v}, {c}]" for v, c in A) + "]", "corrected", A),
    ("seven-pairs", bracket(A + [(8.0, 0.0)]), "corrected", A),
    ("history-echo-after", bracket(A) + "\n(previous: (4.0, 0.0))", "corrected", A),
    ("reasoning-then-list", "The light is red, so we decelerate by about 2 m/s per step.\n\nFinal answer: " + bracket(B), "corrected", B),
    ("stop-go", "Waiting at the light, then accelerating: " + bracket(B), "corrected", B),
    ("spaces-inside-brackets", "[ ( 5.0 , 0.01 ) , ( 5.5 , 0.0 ) , ( 6.0 , -0.02 ) , ( 6.5 , 0.0 ) , ( 7.0 , 0.0 ) , ( 7.5 , 0.003 ) ]", "ok", A),
    ("tabs-and-crlf", bracket(A).replace(", (", ",\r\n\t("), "ok", A),
    ("labels-with-units", lines(A, "v{i} = {v} m/s; c{i} = {c} 1/m"), "corrected", A),
    ("list-marker-numbers", lines(A, "{i}. {v}, {c}"), "corrected", A),
    ("step-colon-numbers", lines(A, "Step {i}: {v} {c}"), "corrected", A),
    ("fence-and-labels", "```\n" + lines(A, "v{i}={v}, c{i}={c}") + "\n```", "corrected", A),
    # --- failed: nothing usable
    ("empty", "", "failed", None),
    ("whitespace-only", "   \n\t ", "failed", None),
    ("refusal", "I'm sorry, but I can't help with predicting driving actions.", "failed", None),
    ("too-few-pairs", bracket(A[:5]), "failed", None),
    ("too-few-numbers", "5.0 0.01 5.5 0.0 6.0", "failed", None),
    ("nan-value", bracket(A).replace("0.003", "nan"), "failed", None),
    ("inf-value", bracket(A).replace("7.5", "inf"), "failed", None),
    ("overflow-value", bracket(A).replace("7.5", "1e999"), "failed", None),
    ("words-only", "Accelerate gently, keep the lane, then slow down for the pedestrian.", "failed", None),
    ("digits-in-words-only", "v1 v2 v3 v4 v5 v6 c1 c2 c3 c4 c5 c6 step1 step2", "failed", None),
    ("placeholder-format", "[(v1, c1), (v2, c2), (v3, c3), (v4, c4), (v5, c5), (v6, c6)]", "failed", None),
    ("api-error-text", "Error: 429 Too Many Requests", "failed", None),
]
