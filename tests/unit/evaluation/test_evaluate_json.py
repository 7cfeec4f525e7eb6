"""``lightemma evaluate --format json``: every column carries its descriptor, the document its provenance, and it is
valid against the package's JSON Schema; documents of another version or edited by hand are refused in one line."""

from __future__ import annotations

import copy
import json

import jsonschema
import pytest

from lightemma.cli import main
from lightemma.errors import UserError
from lightemma.evaluation.descriptors import EVALUATE_FORMAT, check_evaluation_json, read_evaluation_json, schema
from lightemma.runs.store import find_run_dirs, read_manifest


@pytest.fixture(scope="module")
def runs(synth_root, tmp_path_factory):
    out = tmp_path_factory.mktemp("json_runs")
    for kind, extra in (("cv", []), ("constant", ["--limit", "6"])):
        assert (
            main(
                [
                    "run",
                    "--model",
                    f"baseline:{kind}",
                    "--dataroot",
                    str(synth_root),
                    "--version",
                    "v1.0-mini",
                    "--split",
                    "all",
                    "--out",
                    str(out / "runs"),
                    *extra,
                ]
            )
            == 0
        )
    return out / "runs"


def _evaluate(runs, capsys, *args):
    capsys.readouterr()
    assert main(["evaluate", str(runs), "--resamples", "50", *args]) == 0
    return capsys.readouterr().out


@pytest.fixture(scope="module")
def document(runs):
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):
        assert (
            main(
                [
                    "evaluate",
                    str(runs),
                    "--resamples",
                    "50",
                    "--format",
                    "json",
                    "--convention",
                    "all",
                    "--pairwise",
                    "--with-paper",
                ]
            )
            == 0
        )
    return json.loads(buf.getvalue())


def test_the_document_is_valid_against_the_packaged_schema(document):
    validator = jsonschema.Draft202012Validator(schema())
    validator.check_schema(schema())
    assert sorted(e.message for e in validator.iter_errors(document)) == []
    assert document["format"] == EVALUATE_FORMAT
    broken = copy.deepcopy(document)
    broken["provenance"]["frame_sets"] = {"x": {"format": "lightemma-frames/1"}}
    assert list(validator.iter_errors(broken)), "the schema must reject a fingerprint without its fields"


def test_every_emitted_column_has_a_descriptor(document):
    tables = {t["name"]: t for t in document["tables"]}
    assert {
        "efficiency",
        "accuracy_lightemma",
        "accuracy_stp3",
        "accuracy_uniad",
        "safety_lightemma",
        "pairwise_ade",
    } <= set(tables)
    for name, table in tables.items():
        keys = {k for row in table["rows"] for k in row}
        described = document["columns"][name]
        assert keys == set(described), name
        assert [k for k in sorted(keys) if described[k] is None] == [], f"{name}: columns without a descriptor"
    acc = {c: document["columns"][f"accuracy_{c}"] for c in ("lightemma", "stp3", "uniad")}
    assert (acc["lightemma"]["ade_avg"]["id"], acc["stp3"]["ade_2s"]["id"], acc["uniad"]["ade_3s"]["id"]) == (
        "ade@lightemma/1",
        "l2@stp3/1",
        "l2@uniad/1",
    )
    assert (
        acc["lightemma"]["collision"]["id"],
        acc["stp3"]["collision_1s"]["id"],
        acc["uniad"]["collision"]["id"],
    ) == ("collision@any/1", "collision@stp3/1", "collision@uniad/1")
    assert acc["lightemma"]["miss_rate"]["id"] == "miss@2m/1" and acc["lightemma"]["miss_rate"]["range"] == [0.0, 1.0]
    assert acc["lightemma"]["fe_pct"] == {
        "id": "fe@paper/1",
        "title": acc["lightemma"]["fe_pct"]["title"],
        "kind": "rate",
        "unit": "%",
        "range": [0.0, 100.0],
        "lower_is_better": True,
        "version": 1,
        "source": "LightEMMA paper, Table II",
        "anchor": "docs/definitions.md#format-errors",
    }
    assert (
        acc["lightemma"]["offroad"]["id"] == "offroad@footprint/1"
        and acc["lightemma"]["offroad_centre"]["id"] == "offroad@centre/1"
    )


def test_provenance_names_frame_sets_software_prompts_parse_and_sources(document, runs):
    prov = document["provenance"]
    dirs = find_run_dirs(runs)
    recorded = {
        read_manifest(d)["dataset"]["fingerprint"]["id"]: read_manifest(d)["dataset"]["fingerprint"] for d in dirs
    }
    assert prov["frame_sets"] == recorded and len(recorded) == 2  # the full set and the first 6 frames
    assert {fp["n_frames"] for fp in recorded.values()} == {12, 6}
    assert prov["lightemma_version"] and "git_revision" in prov
    for run in prov["runs"]:
        assert run["frame_set"] in recorded and run["prompt_set"]["name"] == "lightemma-v1"
        assert (
            run["prompt_set"]["hash"].startswith("sha256:")
            and run["parse"] == "lenient"
            and run["integrator"] == "euler"
        )
        assert run["safety_source"]["drivable_area"] == "expansion" and run["safety_source"]["version"] == "v1.0-mini"
        assert run["safety_source"]["collision_conventions"] == {"lightemma": "any", "stp3": "stp3", "uniad": "uniad"}
    paper = prov["paper"]
    assert paper["frame_set"] == {"version": "v1.0-test", "split": "test", "window": "reference", "n_frames": 3908}
    assert (paper["ade"], paper["fe"], paper["parse"], paper["integrator"]) == (
        "ade@lightemma/1",
        "fe@paper/1",
        "paper",
        "euler",
    )


def test_the_old_keys_are_all_still_there(document):
    assert {"common", "n_common", "parse", "keep_implausible", "resampling", "warnings", "tables"} <= set(document)


def test_reading_back_checks_everything(document, tmp_path):
    path = tmp_path / "ev.json"
    path.write_text(json.dumps(document), encoding="utf-8")
    assert read_evaluation_json(path) == document


def _acc(doc, convention="lightemma"):
    t = next(i for i, t in enumerate(doc["tables"]) if t["name"] == f"accuracy_{convention}")
    return t, doc["tables"][t]["rows"]


def _refusal(doc, tmp_path):
    path = tmp_path / "ev.json"
    path.write_text(json.dumps(doc), encoding="utf-8")
    with pytest.raises(UserError) as info:
        read_evaluation_json(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"{path}: ")
    return message


def test_a_document_of_another_version_is_refused(document, tmp_path):
    for fmt in ("lightemma-evaluate/2", None):
        doc = copy.deepcopy(document)
        doc["format"] = fmt
        assert ": format: " in _refusal(doc, tmp_path)
    doc = copy.deepcopy(document)
    doc["columns"]["accuracy_stp3"]["ade_1s"]["id"] = "l2@stp3/2"
    assert ": columns.accuracy_stp3.ade_1s.id: 'l2@stp3/2' is not this lightemma's 'l2@stp3/1'" in _refusal(
        doc, tmp_path
    )
    doc = copy.deepcopy(document)
    del doc["columns"]["efficiency"]["gpus"]
    assert ": columns.efficiency.gpus: no descriptor for this column" in _refusal(doc, tmp_path)


def test_a_hand_edited_fingerprint_is_refused(document, tmp_path):
    doc = copy.deepcopy(document)
    key = next(iter(doc["provenance"]["frame_sets"]))
    doc["provenance"]["frame_sets"][key]["n_frames"] += 1
    message = _refusal(doc, tmp_path)
    assert f"provenance.frame_sets.{key}.id: {key} does not match its fields" in message


def test_a_value_its_descriptor_does_not_allow_is_refused(document, tmp_path):
    doc = copy.deepcopy(document)
    t, rows = _acc(doc)
    rows[0]["offroad"] = 1.5  # a rate above 1
    assert f": tables[{t}].rows[0].offroad: 1.5 is outside [0, 1] (offroad@footprint/1, unit share)" in _refusal(
        doc, tmp_path
    )
    doc = copy.deepcopy(document)
    t, rows = _acc(doc, "uniad")
    rows[1]["ade_avg"] = -0.1
    assert f": tables[{t}].rows[1].ade_avg: -0.1 is outside [0, inf] (l2@uniad/1, unit m)" in _refusal(doc, tmp_path)
    doc = copy.deepcopy(document)
    t, rows = _acc(doc)
    rows[0]["fe_pct"] = 101.0
    assert f": tables[{t}].rows[0].fe_pct: 101.0 is outside [0, 100]" in _refusal(doc, tmp_path)
    doc = copy.deepcopy(document)
    t, rows = _acc(doc)
    rows[0]["offroad_ci95"] = [0.0, 1.2]
    assert f": tables[{t}].rows[0].offroad_ci95: 1.2 is outside [0, 1]" in _refusal(doc, tmp_path)


def test_check_without_a_file(document):
    doc = copy.deepcopy(document)
    doc["provenance"]["miss_threshold_m"] = -1
    with pytest.raises(UserError, match=r"^<json>: provenance\.miss_threshold_m: -1 is not a positive number"):
        check_evaluation_json(doc)


def test_a_miss_threshold_is_in_the_miss_rates_id(runs, capsys):
    doc = json.loads(_evaluate(runs, capsys, "--format", "json", "--miss-threshold", "3.5", "--no-safety"))
    assert doc["columns"]["accuracy_lightemma"]["miss_rate"]["id"] == "miss@3.5m/1"
    assert doc["provenance"]["miss_threshold_m"] == 3.5
    check_evaluation_json(doc)


@pytest.mark.parametrize("fmt", ["md", "csv", "latex"])
def test_text_formats_carry_a_compact_footer(runs, capsys, fmt):
    text = _evaluate(runs, capsys, "--format", fmt)
    ids = {read_manifest(d)["dataset"]["fingerprint"]["id"] for d in find_run_dirs(runs)}
    tail = text[text.index("rovenance") :]
    mark = {"md": "- ", "csv": "# ", "latex": "% "}[fmt]
    for fp in ids:
        assert f"{mark}Frame set {fp} (v1.0-mini, split all, reference window, " in tail
    assert (
        "ade@lightemma/1, fde/1, miss@2m/1, fe@paper/1, collision@any/1, offroad@footprint/1, offroad@centre/1" in tail
    )
    assert f"{mark}lightemma " in tail


def test_the_report_has_a_provenance_panel(runs, tmp_path, capsys):
    assert main(["report", str(runs), "--out", str(tmp_path / "rep"), "--resamples", "0"]) == 0
    capsys.readouterr()
    index = (tmp_path / "rep" / "index.md").read_text(encoding="utf-8")
    page = (tmp_path / "rep" / "index.html").read_text(encoding="utf-8")
    assert "### Provenance" in index and 'id="table-provenance"' in page
    for run_dir in find_run_dirs(runs):
        fp = read_manifest(run_dir)["dataset"]["fingerprint"]["id"]
        assert f"| Frame set {fp} (v1.0-mini, split all, reference window, " in index and fp in page
    numbers = json.loads((tmp_path / "rep" / "tables" / "evaluation.json").read_text(encoding="utf-8"))
    assert set(numbers["provenance"]["frame_sets"]) == {
        read_manifest(d)["dataset"]["fingerprint"]["id"] for d in find_run_dirs(runs)
    }


def test_evaluate_refuses_to_print_a_value_its_descriptor_forbids(runs, capsys, monkeypatch):
    """A computation that went wrong (here: an FE rate of 150 %) is one line and exit 2, never a valid-looking JSON."""
    import lightemma.evaluation.core as core

    real = core.format_errors
    monkeypatch.setattr(core, "format_errors", lambda run, rows: {**real(run, rows), "fe_pct": 150.0})
    capsys.readouterr()
    assert main(["evaluate", str(runs), "--resamples", "0", "--format", "json", "--no-safety"]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert [line for line in err.splitlines() if "error" in line] == [
        "lightemma evaluate: error: lightemma evaluate --format json: tables[1].rows[0].fe_pct: 150.0 is outside "
        "[0, 100] (fe@paper/1, unit %)"
    ]
