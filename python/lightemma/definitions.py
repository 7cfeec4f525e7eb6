"""lightemma's definitions, in one place: the names and numbers every module shares (``docs/definitions.md``).

Where the Rust core has a definition it is the source, re-exported here from ``lightemma._core``
(``rust/definitions.rs``, ``rust/parse/mod.rs``, ``rust/metrics.rs``, ``rust/kinematics.rs``); the rest is defined here.
``tests/unit/package/test_definitions.py`` checks that both languages, and every kernel's defaults, agree. Every other module
imports these names from here.

Two different code lists describe what became of an answer, under different names:

* :data:`PARSE_FAILURES`: why the parser failed an answer (the parser's codes, ``_core.parse_actions``);
* :data:`OUTCOMES`: what became of a frame in evaluation (its own codes, ``RunData.failure``), which adds
  ``api_error`` and evaluation's own plausibility check to the parser's kinds.

Both name their kinds with the same strings: the ``failure`` field of a run record (on disk) holds one.
"""

from __future__ import annotations

from lightemma import _core

# ---- the chain -------------------------------------------------------------------------------------------------

#: the three stages of a LightEMMA call chain, in order: describe the scene, state the intent, give the actions
#: (docs/definitions.md#the-three-stages); the keys of a prompt variant's templates and of a run record's stages
STAGES: tuple[str, ...] = ("scene", "intent", "actions")

#: seconds between two actions, and between two nuScenes keyframes (docs/definitions.md#integration)
STEP_SECONDS: float = float(_core.STEP_SECONDS)

#: how actions become positions (``lightemma.integrate``'s ``method``), from ``_core.METHODS``
INTEGRATION_METHODS: tuple[str, ...] = tuple(_core.METHODS)

# ---- parsing an answer -----------------------------------------------------------------------------------------

#: the parse rules (``lightemma.parse_actions``'s ``mode``, docs/parsing.md), from ``_core.PARSE_MODES``
PARSE_MODES: tuple[str, ...] = tuple(_core.PARSE_MODES)

#: how an answer parsed, by the parser's status code: ``ok`` (the strict format; paper mode: its literal rule),
#: ``corrected`` (only the lenient reading, or the paper's digit-run rule, found it), ``failed`` (no usable actions).
#: A run record's ``status`` and ``first_status`` hold one of these. From ``_core.PARSE_STATUSES``.
STATUSES: tuple[str, ...] = tuple(_core.PARSE_STATUSES)
#: status name → code, as evaluation stores a record's status (``RunData.status``; the parser's codes)
STATUS_CODES: dict[str, int] = {name: code for code, name in enumerate(STATUSES)}

#: why the parser failed an answer, by the parser's failure code (0 = not failed): ``""``, ``truncated``,
#: ``implausible``, ``format``, ``ambiguous`` (docs/parsing.md). From ``_core.PARSE_FAILURES``.
PARSE_FAILURES: tuple[str, ...] = tuple(_core.PARSE_FAILURES)

# ---- what became of a frame ------------------------------------------------------------------------------------

#: what became of a frame in evaluation, by outcome code (``RunData.failure``; 0 = not failed, scored when its
#: ground truth is usable). These codes are evaluation's own, not the parser's: new kinds go at the end, so that
#: the codes stay stable (docs/statistics.md).
OUTCOMES: tuple[str, ...] = ("", "format", "truncated", "implausible", "api_error", "ambiguous")
#: outcome name → outcome code
OUTCOME_CODES: dict[str, int] = {name: code for code, name in enumerate(OUTCOMES)}
#: the outcomes counted as "failed" (the answer could not be read), apart from implausible and API errors
UNREADABLE: tuple[str, ...] = ("format", "truncated", "ambiguous")

# ---- conventions -----------------------------------------------------------------------------------------------

#: ADE/FDE conventions (docs/definitions.md#metrics), from ``_core.CONVENTIONS``
CONVENTIONS: tuple[str, ...] = tuple(_core.CONVENTIONS)
#: collision conventions (docs/definitions.md#safety): ``uniad`` (at 1/2/3 s), ``stp3`` (per-step rate), ``any``
COLLISION_CONVENTIONS: tuple[str, ...] = ("uniad", "stp3", "any")
#: which collision convention an ADE table shows beside it (the ADE conventions carry the same names)
COLLISION_FOR_ADE: dict[str, str] = {"uniad": "uniad", "stp3": "stp3", "lightemma": "any"}

# ---- the ego box (docs/definitions.md#safety) ------------------------------------------------------------------

#: length × width of the ego box, metres: ST-P3's and UniAD's (the Renault Zoe is 4.084 m long and 1.73 m wide
#: without mirrors; 1.85 m is their margin). From ``_core.EGO_LENGTH`` / ``_core.EGO_WIDTH``.
EGO_LENGTH: float = float(_core.EGO_LENGTH)
EGO_WIDTH: float = float(_core.EGO_WIDTH)
#: how far the box's centre lies ahead of the ``ego_pose`` reference point (the rear-axle centre), metres:
#: nuScenes' LIDAR_TOP sits 0.943713 m ahead of the rear axle (``calibrated_sensor``) and UniAD shifts the ego box
#: 0.5 m forward in the LiDAR frame: 1.443713 m. From ``_core.EGO_OFFSET``; every safety kernel defaults to it.
EGO_OFFSET: float = float(_core.EGO_OFFSET)
#: a trajectory step shorter than this keeps the previous heading, metres (BEV-Planner's rule), ``_core.MIN_STEP``
MIN_STEP: float = float(_core.MIN_STEP)
#: the planning score's Zoe (``lightemma.planning``): its box centre lies this far ahead of the rear axle, metres —
#: :data:`EGO_OFFSET` rounded to the millimetre, as docs/definitions.md writes it. The planning kernels default to
#: it; making them use :data:`EGO_OFFSET` itself would change planning scores, so it stays a separate value
#: until that change is made on purpose. From ``_core.ZOE_REAR_AXLE_TO_CENTER`` (``Vehicle::ZOE``).
ZOE_REAR_AXLE_TO_CENTER: float = float(_core.ZOE_REAR_AXLE_TO_CENTER)

__all__ = [
    "COLLISION_CONVENTIONS",
    "COLLISION_FOR_ADE",
    "CONVENTIONS",
    "EGO_LENGTH",
    "EGO_OFFSET",
    "EGO_WIDTH",
    "INTEGRATION_METHODS",
    "MIN_STEP",
    "OUTCOMES",
    "OUTCOME_CODES",
    "PARSE_FAILURES",
    "PARSE_MODES",
    "STAGES",
    "STATUSES",
    "STATUS_CODES",
    "STEP_SECONDS",
    "UNREADABLE",
    "ZOE_REAR_AXLE_TO_CENTER",
]
