"""Numbers scored against a map carry the map expansion's version (docs/evaluate.md#what-each-number-is): read from the
expansion JSON's ``version`` (``1.0`` when it has none, as the devkit), recorded in every safety and planning row, in
the descriptors of the map-dependent columns, in the provenance and the footers; runs scored against different versions
of one map are refused together, and evaluations made against different maps do not merge."""

from __future__ import annotations

import contextlib
import io
import json
import shutil

import pytest

from lightemma.cli import main
from lightemma.errors import DatasetError
from lightemma.nuscenes.map_files import read_expansion

MAP_BLOCK = {"drivable_area": "expansion", "expansion_version": "1.3"}


def _set_version(root, version):
    """Every map expansion of ``root`` with ``version`` (None: the field removed)."""
    for path in sorted((root / "maps" / "expansion").glob("*.json")):
        doc = json.loads(path.read_text(encoding="utf-8"))
        if version is None:
            doc.pop("version", None)
        else:
            doc["version"] = version
        path.write_text(json.dumps(doc), encoding="utf-8")


@pytest.fixture(scope="module")
def roots(synth_root, tmp_path_factory):
    """The synthetic dataset (map expansion 1.3) and a copy of it whose expansions say 1.2."""
    old = tmp_path_factory.mktemp("old_maps") / "synth"
    shutil.copytree(synth_root, old)
    _set_version(old, "1.2")
    return synth_root, old


@pytest.fixture(scope="module")
def runs(roots, tmp_path_factory):
    """cv on the 1.3 dataset, constant on the 1.3 one, constant on the 1.2 copy: same frames, each its own dataroot."""
    base = tmp_path_factory.mktemp("map_version_runs")
    out = {}
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        for name, kind, root in (
            ("cv", "cv", roots[0]),
            ("constant", "constant", roots[0]),
            ("old", "constant", roots[1]),
        ):
            assert (
                main(
                    [
                        "run",
                        "--model",
                        f"baseline:{kind}",
                        "--dataroot",
                        str(root),
                        "--version",
                        "v1.0-mini",
                        "--split",
                        "all",
                        "--out",
                        str(base / name),
                    ]
                )
                == 0
            )
            out[name] = base / name
    return out


def _evaluate(capsys, *args):
    capsys.readouterr()
    rc = main(["evaluate", *map(str, args), "--resamples", "0", "--no-explanations"])
    got = capsys.readouterr()
    return rc, got.out, got.err


def test_the_version_is_read_from_the_expansion(synth_root, tmp_path):
    path = next((synth_root / "maps" / "expansion").glob("*.json"))
    assert read_expansion(path).version == "1.3"  # lightemma synth writes the devkit's current 1.3
    copy = tmp_path / "synth"
    shutil.copytree(synth_root / "maps", copy / "maps")
    target = copy / "maps" / "expansion" / path.name
    _set_version(copy, "1.2")
    assert read_expansion(target).version == "1.2"
    _set_version(copy, None)
    assert read_expansion(target).version == "1.0"  # no field: 1.0, as the devkit's NuScenesMap reads it
    for bad in (1.3, "latest", ["1.3"]):
        _set_version(copy, bad)
        with pytest.raises(DatasetError) as err:
            read_expansion(target)
        msg = str(err.value)
        assert str(target) in msg and "version" in msg and "\n" not in msg, msg


def test_json_descriptors_rows_and_provenance_carry_the_version(runs, capsys):
    rc, out, err = _evaluate(capsys, runs["cv"], "--format", "json")
    assert rc == 0, err
    doc = json.loads(out)
    acc = next(t for t in doc["tables"] if t["name"] == "accuracy_lightemma")
    assert {r.get("map_version") for r in acc["rows"]} == {"1.3"}  # the run's row and the floor's
    for key in ("offroad", "offroad_1s", "offroad_centre", "offroad_ci95"):
        assert doc["columns"]["accuracy_lightemma"][key]["map"] == MAP_BLOCK, key
    assert "map" not in doc["columns"]["accuracy_lightemma"]["ade_avg"]  # ADE does not depend on a map
    assert "map" not in doc["columns"]["accuracy_lightemma"]["collision"]
    planning = next(t for t in doc["tables"] if t["name"] == "planning")
    assert {r.get("map_version") for r in planning["rows"]} == {"1.3"}
    for key in ("dac", "ddc", "pdms", "epdms"):
        assert doc["columns"]["planning"][key]["map"] == MAP_BLOCK, key
    (run,) = doc["provenance"]["runs"]
    assert run["safety_source"]["map_expansion_version"] == "1.3"
    assert run["planning_source"]["map_expansion_version"] == "1.3"
    import jsonschema

    from lightemma.evaluation.descriptors import check_evaluation_json, schema

    assert [e.message for e in jsonschema.Draft202012Validator(schema()).iter_errors(doc)] == []
    edited = json.loads(out)  # a descriptor's map edited by hand no longer matches its rows
    edited["columns"]["accuracy_lightemma"]["offroad"]["map"]["expansion_version"] = "1.2"
    with pytest.raises(Exception, match=r"columns\.accuracy_lightemma\.offroad\.map"):
        check_evaluation_json(edited, "ev.json")


def test_text_formats_say_the_version_in_their_footer(runs, capsys):
    for fmt, mark in (("md", "- Maps: "), ("csv", "# Maps: "), ("latex", "% Maps: ")):
        rc, out, err = _evaluate(capsys, runs["cv"], "--format", fmt)
        assert rc == 0, err
        assert f"{mark}drivable area expansion, map expansion 1.3" in out, fmt


def test_the_report_panel_names_the_version(runs):
    from lightemma.evaluation import evaluate_runs
    from lightemma.evaluation.stats import Resampling
    from lightemma.report.evaluation_tables import provenance_table

    evaluation = evaluate_runs([runs["cv"]], resampling=Resampling(n_resamples=0), explanations=False)
    rows = {r["item"]: r["value"] for r in provenance_table(evaluation).rows}
    assert rows["Maps"] == "drivable area expansion, map expansion 1.3"
    (label,) = [m.label for m in evaluation.models]
    assert "drivable area expansion (map expansion 1.3)" in rows[label]


def test_runs_on_different_map_versions_are_refused_in_one_line(runs, capsys):
    rc, out, err = _evaluate(capsys, runs["cv"], runs["constant"])  # one map version: as before
    assert rc == 0, err
    rc, out, err = _evaluate(capsys, runs["cv"], runs["old"])
    assert rc != 0 and out == ""
    lines = [line for line in err.splitlines() if line.strip() and "warning" not in line]
    assert len(lines) == 1, err
    line = lines[0]
    assert "Baseline (constant velocity)" in line and "Baseline (constant actions)" in line, line
    assert "1.2" in line and "1.3" in line and "map expansion" in line and "not comparable" in line, line
    rc, out, err = _evaluate(capsys, runs["cv"], runs["old"], "--no-safety", "--no-planning")  # no map, no conflict
    assert rc == 0, err


def test_evaluations_against_different_maps_do_not_merge(runs, capsys, tmp_path):
    for name in ("cv", "old"):
        rc, out, err = _evaluate(capsys, runs[name], "--format", "json", "-o", tmp_path / f"{name}.json")
        assert rc == 0, err
    capsys.readouterr()
    rc = main(["evaluate", "--merge", str(tmp_path / "cv.json"), str(tmp_path / "old.json")])
    got = capsys.readouterr()
    assert rc != 0 and got.out == ""
    lines = [line for line in got.err.splitlines() if line.strip()]
    assert len(lines) == 1 and ".map" in lines[0] and "1.3" in lines[0] and "1.2" in lines[0], got.err
