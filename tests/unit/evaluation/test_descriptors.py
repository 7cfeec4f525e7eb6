"""The metric registry (lightemma.evaluation.descriptors): ids, versions, units, ranges, sources and anchors as data."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from lightemma.errors import UserError
from lightemma.evaluation.descriptors import (
    ADE_BY_CONVENTION,
    COLLISION_BY_CONVENTION,
    FIELDS,
    METRICS,
    PLANNING_BY_KEY,
    column_descriptors,
    describe,
    miss_descriptor,
)

ROOT = Path(__file__).resolve().parents[3]
ID = re.compile(r"[a-z0-9_]+(@[A-Za-z0-9_.]+)?/[1-9][0-9]*")


def _anchors(page: Path) -> set[str]:
    """GitHub's heading anchors of a Markdown page."""
    out = set()
    for line in page.read_text(encoding="utf-8").splitlines():
        if line.startswith("#"):
            title = line.lstrip("#").strip().lower()
            out.add(re.sub(r"\s", "-", re.sub(r"[^\w\s-]", "", title)))
    return out


def test_the_issues_ids_are_there():
    for id_ in (
        "ade@lightemma/1",
        "l2@stp3/1",
        "l2@uniad/1",
        "fde/1",
        "collision@uniad/1",
        "offroad@footprint/1",
        "fe@paper/1",
        "epdms@nuscenes/1",
    ):
        assert id_ in METRICS
    assert miss_descriptor(2.0).id == "miss@2m/1" and miss_descriptor(2.5).id == "miss@2.5m/1"


def test_every_descriptor_is_complete_and_consistent():
    every = [*METRICS.values(), *FIELDS.values(), miss_descriptor(2.0)]
    for d in every:
        assert ID.fullmatch(d.id), d.id
        assert d.version == int(d.id.rsplit("/", 1)[1]) and d.name == d.id.rsplit("/", 1)[0]
        assert d.kind in ("metric", "rate", "count", "interval", "test", "label") and d.title and d.source
        if d.kind == "rate":
            assert (d.unit, d.range) in (("share", (0.0, 1.0)), ("%", (0.0, 100.0))), d.id
        if d.kind == "label":
            assert d.unit is None and d.range is None and d.lower_is_better is None, d.id
        if d.range is not None and None not in d.range:
            assert d.range[0] < d.range[1]
    # one id, one definition: descriptors sharing an id agree on unit, range, kind and source
    by_id: dict[str, set] = {}
    for d in every:
        by_id.setdefault(d.id, set()).add((d.kind, d.unit, d.range, d.source))
    assert {k: v for k, v in by_id.items() if len(v) > 1 and not k.startswith(("ci95@", "diff@"))} == {}
    for d in METRICS.values():
        assert d.lower_is_better is not None, f"{d.id}: a score says which way is better"


def test_every_anchor_is_a_heading_of_its_page():
    every = [*METRICS.values(), *FIELDS.values(), miss_descriptor(2.0)]
    for d in every:
        page, anchor = d.anchor.split("#")
        assert anchor in _anchors(ROOT / page), d.anchor


def test_columns_map_to_their_conventions():
    for convention, id_ in ADE_BY_CONVENTION.items():
        for key in ("ade_1s", "ade_2s", "ade_3s", "ade_avg"):
            assert describe(key, convention=convention).id == id_
        assert describe("fde", convention=convention).id == "fde/1"
    for cc, id_ in COLLISION_BY_CONVENTION.items():
        for key in ("collision", "collision_1s", "collision_vru", "collision_vehicle"):
            assert describe(key, collision_convention=cc).id == id_
    assert describe("miss_rate", miss_threshold=3.0).id == "miss@3m/1"
    # a row that does not name its collision convention gets its table's (safety.COLLISION_FOR_ADE)
    from lightemma.evaluation.safety import COLLISION_FOR_ADE

    for convention, cc in COLLISION_FOR_ADE.items():
        assert describe("collision_2s", convention=convention).id == COLLISION_BY_CONVENTION[cc]
    assert describe("offroad_2s").id == "offroad@footprint/1" and describe("offroad_centre").id == "offroad@centre/1"
    for key, id_ in PLANNING_BY_KEY.items():
        assert (
            describe(key).id == id_
            and describe(f"{key}_ci95").kind == "interval"
            and describe(f"{key}_na").kind == "label"
        )
    # paired columns of the ablation and baseline-gain tables: the metric itself, its difference, its statistics
    assert describe("ade_avg_full", convention="uniad").id == "l2@uniad/1"
    assert describe("ade_avg_gain").id == "diff@paired/1" and describe("ade_avg_gain").unit == "m"
    assert describe("ade_avg_p_holm").id == "p@holm/1" and describe("ade_avg_p").id == "p@signflip/1"
    assert describe("ade_avg_significant").id == "significant/1"
    assert describe("no_such_column") is None and describe("no_such_p_holm") is None


def test_a_table_mixing_collision_conventions_is_refused():
    rows = [
        {"model": "a", "collision": 0.1, "collision_convention": "uniad"},
        {"model": "b", "collision": 0.2, "collision_convention": "any"},
    ]
    with pytest.raises(
        UserError, match=r"^table accuracy_uniad: rows under different collision conventions \(any, uniad\)"
    ):
        column_descriptors("accuracy_uniad", rows)
    out = column_descriptors("accuracy_stp3", rows[:1])
    assert out["collision"]["id"] == "collision@uniad/1" and out["model"]["id"] == "model/1"


@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), float("inf"), "2"])
def test_a_miss_threshold_that_is_no_distance_is_refused(bad):
    with pytest.raises(ValueError, match="miss threshold must be a positive number of metres"):
        miss_descriptor(bad)


def _evaluation_doc(rows: list[dict], table: str = "accuracy_lightemma") -> dict:
    """A minimal ``lightemma evaluate --format json`` document: one table, its descriptors, no frame sets."""
    from lightemma.evaluation.descriptors import EVALUATE_FORMAT

    return {
        "format": EVALUATE_FORMAT,
        "provenance": {"frame_sets": {}, "miss_threshold_m": 2.0},
        "columns": {table: column_descriptors(table, rows)},
        "tables": [{"name": table, "title": table, "rows": rows}],
    }


_VALID_ROW = {
    "model": "baseline:cv",
    "convention": "lightemma",
    "frames": 8,
    "frames_accounted": 12,
    "frames_in_run": 12,
    "scored": 10,  # more than "frames" (the frames behind the means) as under --common: allowed
    "failed": 2,
    "ade_avg": 1.25,
    "offroad": 0.0,
    "fde": None,
    "ade_avg_ci95": [1.0, 1.5],
    "fde_ci95": None,
    "offroad_ci95": [0.0, None],
}


def _read(doc: dict, tmp_path: Path) -> tuple[Path, dict]:
    import json

    from lightemma.evaluation.descriptors import read_evaluation_json

    path = tmp_path / "ev.json"
    path.write_text(json.dumps(doc), encoding="utf-8")
    return path, read_evaluation_json(path)


def test_a_valid_evaluation_document_is_read_back(tmp_path):
    doc = _evaluation_doc([dict(_VALID_ROW)])
    assert _read(doc, tmp_path)[1] == doc
    # a paired difference's interval may lie below zero, ordered
    rows = [{"model": "a", "ablation": "no_image", "frames": 4, "ade_avg_diff": -0.3, "ade_avg_ci95": [-0.5, -0.1]}]
    doc = _evaluation_doc(rows, "input_ablations")
    assert _read(doc, tmp_path)[1] == doc


@pytest.mark.parametrize(
    ("key", "value", "why"),
    [
        ("ade_avg", "abc", r"'abc' is not a finite number \(ade@lightemma/1, unit m\)"),
        ("ade_avg", True, r"True is not a finite number"),
        ("ade_avg", [1, 2], r"\[1, 2\] is not a finite number"),
        ("offroad", "1.5", r"'1.5' is not a finite number \(offroad@footprint/1, unit share\)"),
        ("frames", 2.5, r"2.5 is not a whole number \(frames/1, unit frames\)"),
        ("scored", 13, r"13 is more than frames_accounted 12"),
        ("frames_accounted", 13, r"13 is more than frames_in_run 12"),
        ("ade_avg_ci95", [2.0, 1.0], r"\[2.0, 1.0\] is reversed: low 2.0 > high 1.0"),
        ("ade_avg_ci95", [1.0], r"\[1.0\] is not an interval \[low, high\]"),
        ("ade_avg_ci95", "1.0-2.0", r"'1.0-2.0' is not an interval"),
        ("ade_avg_ci95", [1.0, "2"], r"'2' is not a finite number"),
    ],
)
def test_an_evaluation_value_of_the_wrong_type_is_refused(tmp_path, key, value, why):
    row = {**_VALID_ROW, key: value}
    doc = _evaluation_doc([row])
    with pytest.raises(UserError) as info:
        _read(doc, tmp_path)
    message = str(info.value)
    assert "\n" not in message
    assert re.match(rf"^{re.escape(str(tmp_path / 'ev.json'))}: tables\[0\]\.rows\[0\]\.{key}: {why}", message), message


def test_a_reversed_paired_difference_interval_is_refused(tmp_path):
    rows = [{"model": "a", "ablation": "no_image", "frames": 4, "ade_avg_diff": -0.3, "ade_avg_ci95": [-0.1, -0.5]}]
    with pytest.raises(UserError, match=r"tables\[0\]\.rows\[0\]\.ade_avg_ci95: \[-0.1, -0.5\] is reversed"):
        _read(_evaluation_doc(rows, "input_ablations"), tmp_path)
