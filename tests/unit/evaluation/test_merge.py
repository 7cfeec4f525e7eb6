"""``lightemma evaluate --merge A.json B.json …``: tables of earlier evaluations joined only where metric ids,
versions and frame sets agree; any mismatch or bad file is refused in one line naming the files and the field, nothing
written."""

from __future__ import annotations

import json

import jsonschema
import pytest

from lightemma.cli import main
from lightemma.evaluation.descriptors import check_evaluation_json, schema


def _run(out, kind, *extra):
    assert (
        main(
            [
                "run",
                "--model",
                f"baseline:{kind}",
                "--dataroot",
                str(out["root"]),
                "--version",
                "v1.0-mini",
                "--split",
                "all",
                "--out",
                str(out["dir"]),
                *extra,
            ]
        )
        == 0
    )


@pytest.fixture(scope="module")
def files(synth_root, tmp_path_factory):
    """Evaluations written on three occasions: cv and constant on the whole frame set, constant on 6 frames."""
    import contextlib
    import io

    base = tmp_path_factory.mktemp("merge")
    out: dict = {}
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        for name, kind, extra in (("cv", "cv", []), ("const", "constant", []), ("six", "constant", ["--limit", "6"])):
            _run({"root": synth_root, "dir": base / name}, kind, *extra)
            path = base / f"{name}.json"
            assert main(["evaluate", str(base / name), "--resamples", "20", "--format", "json", "-o", str(path)]) == 0
            out[name] = path
        path = base / "cv_pairwise.json"
        assert (
            main(
                [
                    "evaluate",
                    str(base / "cv"),
                    str(base / "six"),
                    "--common",
                    "--pairwise",
                    "--resamples",
                    "20",
                    "--format",
                    "json",
                    "-o",
                    str(path),
                ]
            )
            == 0
        )
        out["pairwise"] = path
        path = base / "cv_miss3.json"
        assert (
            main(
                [
                    "evaluate",
                    str(base / "cv"),
                    "--resamples",
                    "20",
                    "--miss-threshold",
                    "3",
                    "--format",
                    "json",
                    "-o",
                    str(path),
                ]
            )
            == 0
        )
        out["miss3"] = path
    return out


def _merge(capsys, *args):
    capsys.readouterr()
    rc = main(["evaluate", "--merge", *map(str, args)])
    got = capsys.readouterr()
    return rc, got.out, got.err


def _load(path):
    return json.loads(path.read_text(encoding="utf-8"))


def test_merging_two_evaluations_of_one_frame_set_keeps_every_value(files, capsys, tmp_path):
    target = tmp_path / "board.json"
    rc, _, err = _merge(capsys, files["cv"], files["const"], "-o", target)
    assert rc == 0, err
    merged = _load(target)
    check_evaluation_json(merged, target)
    assert sorted(e.message for e in jsonschema.Draft202012Validator(schema()).iter_errors(merged)) == []
    a, b = _load(files["cv"]), _load(files["const"])
    assert [t["name"] for t in merged["tables"]] == [t["name"] for t in a["tables"]]
    for i, table in enumerate(merged["tables"]):
        runs_a = [r for r in a["tables"][i]["rows"] if r["model"] == "Baseline (constant velocity)"]
        runs_b = [r for r in b["tables"][i]["rows"] if r["model"] == "Baseline (constant actions)"]
        reference = [r for r in a["tables"][i]["rows"] if r not in runs_a]
        assert table["rows"] == runs_a + runs_b + reference  # values as written, the ground truth's rows once
    assert set(merged["provenance"]["frame_sets"]) == set(a["provenance"]["frame_sets"])
    assert [m["file"] for m in merged["merged_from"]] == [str(files["cv"]), str(files["const"])]
    models = [r["model"] for r in merged["provenance"]["runs"]]
    assert models == ["Baseline (constant velocity)", "Baseline (constant actions)"]


def test_merged_markdown_names_both_models_and_the_frame_set(files, capsys):
    rc, out, err = _merge(capsys, files["cv"], files["const"], "--format", "md")
    assert rc == 0, err
    fs = next(iter(_load(files["cv"])["provenance"]["frame_sets"]))
    assert "| Baseline (constant velocity) |" in out and "| Baseline (constant actions) |" in out
    assert f"Merged on frame set {fs}" in out and "ade@lightemma/1" in out


def _refused(capsys, tmp_path, *paths):
    target = tmp_path / "board.json"
    rc, out, err = _merge(capsys, *paths, "-o", target)
    assert rc != 0 and out == ""
    assert not target.exists()  # nothing written on a refusal
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    return lines[0]


def test_different_frame_sets_are_refused_naming_both_files(files, capsys, tmp_path):
    line = _refused(capsys, tmp_path, files["cv"], files["six"])
    assert str(files["cv"]) in line and str(files["six"]) in line and "provenance.frame_sets" in line
    fps = [next(iter(_load(files[k])["provenance"]["frame_sets"])) for k in ("cv", "six")]
    assert all(fp in line for fp in fps)


def test_a_run_in_two_files_is_refused(files, capsys, tmp_path):
    line = _refused(capsys, tmp_path, files["cv"], files["cv"])
    assert "provenance.runs[].model" in line and "Baseline (constant velocity)" in line


def test_another_miss_threshold_is_refused(files, capsys, tmp_path):
    line = _refused(capsys, tmp_path, files["const"], files["miss3"])
    assert str(files["miss3"]) in line and ("miss_threshold_m" in line or "miss_rate" in line)


def test_paired_comparisons_and_common_frames_are_refused(files, capsys, tmp_path):
    line = _refused(capsys, tmp_path, files["pairwise"], files["const"])
    assert str(files["pairwise"]) in line and ("common" in line or "frame_sets" in line or "tables[" in line)


@pytest.mark.parametrize(
    ("edit", "field"),
    [
        (lambda d: d.__setitem__("format", "lightemma-evaluate/2"), "format"),
        (
            lambda d: d["columns"]["accuracy_lightemma"]["ade_avg"].__setitem__("id", "ade@lightemma/2"),
            "columns.accuracy_lightemma.ade_avg.id",
        ),
        (lambda d: d["tables"][1]["rows"][0].__setitem__("miss_rate", 1.5), "tables[1].rows[0].miss_rate"),
        (
            lambda d: next(iter(d["provenance"]["frame_sets"].values())).__setitem__("n_frames", 5),
            "provenance.frame_sets",
        ),
    ],
    ids=["newer-format", "metric-version", "rate-above-1", "edited-fingerprint"],
)
def test_a_bad_file_is_refused_naming_it_and_the_field(files, capsys, tmp_path, edit, field):
    doc = _load(files["const"])
    assert doc["tables"][1]["name"] == "accuracy_lightemma"
    edit(doc)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc), encoding="utf-8")
    line = _refused(capsys, tmp_path, files["cv"], bad)
    assert str(bad) in line and field in line


def test_merge_takes_json_files_only(files, capsys, tmp_path):
    rc, _, err = _merge(capsys, files["cv"], "--format", "csv")
    assert rc != 0 and "--format json or md" in err
    rc, _, err = _merge(capsys, files["cv"])
    assert rc != 0 and "two or more" in err
    capsys.readouterr()
    assert main(["evaluate"]) != 0
    assert "RUN_DIR" in capsys.readouterr().err


def test_merged_markdown_marks_runs_on_other_prompt_sets(files, capsys, tmp_path):
    doc = _load(files["const"])
    doc["provenance"]["runs"][0]["prompt_set"] = {"name": "lab-v2", "hash": "sha256:0123456789abcdef"}
    other = tmp_path / "const_v2.json"
    other.write_text(json.dumps(doc), encoding="utf-8")
    rc, out, err = _merge(capsys, files["cv"], other, "--format", "md")
    assert rc == 0, err
    note = next(line for line in out.splitlines() if line.startswith("Runs differ in prompt sets:"))
    assert "lab-v2" in note and "lightemma-v1" in note
    rc, out, err = _merge(capsys, files["cv"], files["const"], "--format", "md")
    assert "Runs differ in prompt sets" not in out


def test_options_of_evaluating_runs_are_refused_with_merge(files, capsys):
    rc, out, err = _merge(capsys, files["cv"], files["const"], "--pairwise")
    assert rc != 0 and out == "" and "--pairwise" in err
