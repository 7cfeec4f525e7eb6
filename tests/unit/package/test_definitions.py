"""lightemma.definitions: one set of definitions, and the Rust core agrees with it.

The names come from ``_core`` where Rust has them; these tests check that each means in Rust what Python reads it as
(a status code indexes STATUSES, a failure code PARSE_FAILURES), that every kernel's default is the definition, and
that no module keeps its own copy.
"""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import numpy as np
import pytest

from lightemma import _core
from lightemma import definitions as D

PACKAGE = Path(__file__).resolve().parents[3] / "python" / "lightemma"

#: the safety kernels and their ego-box parameters
SAFETY_KERNELS = ("ego_poses", "footprint_corners", "box_collisions", "mask_area", "polygon_area")


def _default(function: object, name: str) -> object:
    return inspect.signature(function).parameters[name].default  # type: ignore[arg-type]


def test_the_lists_rust_has_are_rusts():
    assert D.INTEGRATION_METHODS == tuple(_core.METHODS) == ("euler", "midpoint")
    assert D.CONVENTIONS == tuple(_core.CONVENTIONS) == ("lightemma", "stp3", "uniad")
    assert D.PARSE_MODES == tuple(_core.PARSE_MODES)
    assert D.PARSE_FAILURES == tuple(_core.PARSE_FAILURES)
    assert D.STATUSES == tuple(_core.PARSE_STATUSES) == ("ok", "corrected", "failed")
    assert D.STATUS_CODES == {"ok": 0, "corrected": 1, "failed": 2}
    assert (D.STEP_SECONDS, D.EGO_LENGTH, D.EGO_WIDTH, D.MIN_STEP) == (0.5, 4.084, 1.85, 1.0)
    assert (_core.STEP_SECONDS, _core.EGO_LENGTH, _core.EGO_WIDTH, _core.MIN_STEP) == (0.5, 4.084, 1.85, 1.0)
    # the LiDAR 0.943713 m ahead of the rear axle, plus UniAD's 0.5 m shift
    assert D.EGO_OFFSET == _core.EGO_OFFSET == 0.943713 + 0.5


def test_rusts_codes_mean_what_python_reads_them_as():
    """A status or failure code from the parser names the status/failure Python maps it to."""
    texts = [
        "[(1.0, 0.0), (1.0, 0.0), (1.0, 0.0), (1.0, 0.0), (1.0, 0.0), (1.0, 0.0)]",  # strict: ok
        "Final: (1.0, 0.0), (1.0, 0.0), (1.0, 0.0), (1.0, 0.0), (1.0, 0.0), (1.0, 0.0) done",  # lenient: corrected
        "[(1.0, 0.0), (1.0, 0.0), (1.0",  # truncated
        "[(99.0, 0.0), (1.0, 0.0), (1.0, 0.0), (1.0, 0.0), (1.0, 0.0), (1.0, 0.0)]",  # implausible
        "no numbers here",  # format
    ]
    _, status, failure, _ = _core.parse_actions(texts)
    assert [D.STATUSES[c] for c in status] == ["ok", "corrected", "failed", "failed", "failed"]
    assert [D.PARSE_FAILURES[c] for c in failure] == ["", "", "truncated", "implausible", "format"]


def test_frame_outcomes_and_parse_failures_are_two_named_code_lists():
    """The parser's failure codes and evaluation's outcome codes are different lists under different names: code 1
    is "truncated" for the parser and "format" for evaluation; every parse failure is an outcome of the same name."""
    import lightemma.actions as actions
    import lightemma.evaluation.outcomes as outcomes

    assert not hasattr(actions, "FAILURES") and not hasattr(outcomes, "FAILURES")
    assert not hasattr(outcomes, "FAILURE_CODES")
    assert D.PARSE_FAILURES[1] == "truncated" and D.OUTCOMES[1] == "format"
    assert set(D.PARSE_FAILURES) <= set(D.OUTCOMES)
    assert D.OUTCOME_CODES == {name: code for code, name in enumerate(D.OUTCOMES)}
    # the on-disk strings and evaluation's codes are the ones runs and reports were made with
    assert D.OUTCOMES == ("", "format", "truncated", "implausible", "api_error", "ambiguous")
    assert set(D.UNREADABLE) < set(D.OUTCOMES)


@pytest.mark.parametrize("kernel", SAFETY_KERNELS)
def test_every_safety_kernel_defaults_to_lightemmas_ego_box(kernel):
    function = getattr(_core, kernel)
    assert _default(function, "length") == D.EGO_LENGTH
    assert _default(function, "width") == D.EGO_WIDTH
    assert _default(function, "offset") == D.EGO_OFFSET
    assert _default(function, "min_step") == D.MIN_STEP


def test_a_safety_kernel_called_without_a_box_uses_lightemmas():
    """The footprint with the kernel's defaults is the footprint of lightemma's ego box (centre 1.44 m ahead)."""
    from lightemma.evaluation import safety

    traj = np.array([[[2.0, 0.0], [4.0, 0.0]]])
    poses = np.zeros((1, 3))
    bare = _core.footprint_corners(traj, poses)
    assert np.array_equal(bare, safety.footprints(traj, poses))
    front_x = bare[0, 0, :, 0].max()  # step 1: reference point at x = 2, heading 0
    assert front_x == pytest.approx(2.0 + D.EGO_OFFSET + D.EGO_LENGTH / 2)


def test_every_other_kernel_default_is_the_definition():
    assert _default(_core.integrate, "dt") == D.STEP_SECONDS
    assert _default(_core.simulate, "plan_dt") == D.STEP_SECONDS
    assert _default(_core.comfort, "rear_axle_to_center") == D.ZOE_REAR_AXLE_TO_CENTER
    assert _default(_core.planning_subscores, "length") == D.EGO_LENGTH
    assert _default(_core.planning_subscores, "width") == D.EGO_WIDTH
    assert _default(_core.planning_subscores, "rear_axle_to_center") == D.ZOE_REAR_AXLE_TO_CENTER
    # the planning score's Zoe rounds lightemma's offset to the millimetre (a separate, documented value)
    assert D.ZOE_REAR_AXLE_TO_CENTER == round(D.EGO_OFFSET, 3)

    from lightemma.kinematics import integrate
    from lightemma.planning import scores, simulation

    assert _default(integrate, "dt") == D.STEP_SECONDS
    assert simulation.ZOE.rear_axle_to_center == D.ZOE_REAR_AXLE_TO_CENTER
    assert (scores.EgoBox().length, scores.EgoBox().width) == (D.EGO_LENGTH, D.EGO_WIDTH)
    assert scores.EgoBox().rear_axle_to_center == D.ZOE_REAR_AXLE_TO_CENTER


#: names a module may not define for itself (they live in lightemma.definitions)
_OWN_NAMES = {
    "DT",
    "KEYFRAME_DT",
    "STATUSES",
    "KNOWN_STATUSES",
    "STATUS_CODES",
    "STAGES",
    "FAILURES",
    "FAILURE_CODES",
    "OUTCOMES",
    "OUTCOME_CODES",
    "UNREADABLE",
    "CONVENTIONS",
    "CONVENTION_NAMES",
    "METHODS",
    "INTEGRATION_METHODS",
    "COLLISION_CONVENTIONS",
    "COLLISION_FOR_ADE",
    "EGO_LENGTH",
    "EGO_WIDTH",
    "EGO_OFFSET",
    "MIN_STEP",
    "PARSE_FAILURES",
    "PARSE_MODES",
    "MODES",
}
#: numbers that are the ego box (the docs may say them; the code takes them from lightemma.definitions)
_OWN_NUMBERS = {4.084, 0.943713, 1.444, 1.443713}


def _definitions_elsewhere() -> list[str]:
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name == "definitions.py" and path.parent == PACKAGE:
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        where = path.relative_to(PACKAGE)
        for node in ast.walk(tree):
            targets: list[ast.expr] = []
            if isinstance(node, ast.Assign) and node.col_offset == 0:
                targets = node.targets
            elif isinstance(node, ast.AnnAssign) and node.col_offset == 0:
                targets = [node.target]
            for target in targets:
                for name in ast.walk(target):
                    if isinstance(name, ast.Name) and name.id in _OWN_NAMES:
                        found.append(f"{where}:{node.lineno} defines {name.id}")
            if isinstance(node, ast.Constant) and type(node.value) is float and node.value in _OWN_NUMBERS:
                found.append(f"{where}:{node.lineno} writes {node.value}")
    return found


def test_no_module_keeps_its_own_copy_of_a_definition():
    assert _definitions_elsewhere() == []
