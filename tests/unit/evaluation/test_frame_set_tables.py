"""Runs on different frame sets are never ranked in one column: ``lightemma evaluate`` prints one table per frame set
(fingerprint in the title) unless ``--common`` scores them on their common frames, and ``--pairwise`` between runs
without a common frame is refused in one line naming both fingerprints."""

from __future__ import annotations

import contextlib
import io
import json

import pytest

from lightemma.cli import main


@pytest.fixture(scope="module")
def runs(synth_root, tmp_path_factory):
    """cv on every scene, constant on the first 6 frames (a subset), oracle on the second scene only (after cv's)."""
    base = tmp_path_factory.mktemp("frame_sets")
    scenes = json.loads((synth_root / "v1.0-mini" / "scene.json").read_text(encoding="utf-8"))
    names = sorted(s["name"] for s in scenes)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        for folder, kind, extra in (
            ("all", "cv", []),
            ("subset", "constant", ["--limit", "6"]),
            ("first", "cv", ["--scenes", names[0]]),
            ("second", "constant", ["--scenes", names[1]]),
        ):
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
                        str(base / folder),
                        *extra,
                    ]
                )
                == 0
            )
    return base


def _evaluate(capsys, *args):
    capsys.readouterr()
    rc = main(["evaluate", *map(str, args), "--resamples", "20", "--no-planning", "--no-safety"])
    got = capsys.readouterr()
    return rc, got.out, got.err


def _titles(out):
    return [line[4:] for line in out.splitlines() if line.startswith("### ")]


def test_runs_on_different_frame_sets_get_a_table_each(runs, capsys):
    rc, out, err = _evaluate(capsys, runs / "all", runs / "subset")
    assert rc == 0, err
    accuracy = [t for t in _titles(out) if t.startswith("Accuracy")]
    assert len(accuracy) == 2 and all("— frame set frames:" in t for t in accuracy)
    assert any("6 frames, limit 6" in t for t in accuracy)
    for block in out.split("### ")[1:]:  # no table ranks the two runs in one column
        assert not ("| Baseline (constant velocity) |" in block and "| Baseline (constant actions) |" in block), block


def test_common_scores_them_together_and_says_so(runs, capsys):
    rc, out, err = _evaluate(capsys, runs / "all", runs / "subset", "--common")
    assert rc == 0, err
    accuracy = [t for t in _titles(out) if t.startswith("Accuracy")]
    assert len(accuracy) == 1 and "scored in every run" in accuracy[0] and "frame set" not in accuracy[0]
    block = next(b for b in out.split("### ")[1:] if b.startswith("Accuracy"))
    assert "| Baseline (constant velocity) |" in block and "| Baseline (constant actions) |" in block


def test_one_frame_set_keeps_one_table(runs, capsys):
    rc, out, err = _evaluate(capsys, runs / "all")
    assert rc == 0, err
    assert not any("frame set" in t for t in _titles(out))


@pytest.mark.parametrize("fmt", ["csv", "latex"])
def test_other_text_formats_split_too(runs, capsys, fmt):
    rc, out, err = _evaluate(capsys, runs / "all", runs / "subset", "--format", fmt)
    assert rc == 0, err
    assert sum("Accuracy" in line and "frame set frames:" in line for line in out.splitlines()) == 2


def test_pairwise_without_common_frames_is_refused_naming_both_fingerprints(runs, capsys):
    rc, out, err = _evaluate(capsys, runs / "first", runs / "second", "--pairwise")
    assert rc != 0 and out == ""
    lines = [line for line in err.splitlines() if line.strip() and "warning" not in line]
    assert len(lines) == 1, err
    fps = []
    for folder in ("first", "second"):
        rc, doc, _ = _evaluate(capsys, runs / folder, "--format", "json")
        fps += list(json.loads(doc)["provenance"]["frame_sets"])
    assert len(set(fps)) == 2 and all(fp in lines[0] for fp in fps), lines[0]
    assert "--pairwise" in lines[0] and "no frame scored in both" in lines[0]


def test_pairwise_with_common_frames_still_runs(runs, capsys):
    rc, out, err = _evaluate(capsys, runs / "all", runs / "subset", "--pairwise")
    assert rc == 0, err
    assert any(t.startswith("Paired comparisons") for t in _titles(out))


def test_json_rows_carry_their_frame_set_and_the_top_lists_the_groups(runs, capsys):
    rc, out, err = _evaluate(capsys, runs / "all", runs / "subset", "--format", "json")
    assert rc == 0, err
    doc = json.loads(out)
    runs_fp = {r["model"]: r["frame_set"] for r in doc["provenance"]["runs"]}
    assert len(set(runs_fp.values())) == 2
    assert sorted((g["frame_set"], tuple(g["models"])) for g in doc["frame_set_groups"]) == sorted(
        (fp, (m,)) for m, fp in runs_fp.items()
    )
    accuracy = next(t for t in doc["tables"] if t["name"] == "accuracy_lightemma")
    assert {r["model"]: r["frame_set"] for r in accuracy["rows"] if r["model"] in runs_fp} == runs_fp
    assert doc["columns"]["accuracy_lightemma"]["frame_set"]["id"] == "frame_set/1"
    rc, out, _ = _evaluate(capsys, runs / "all", "--format", "json")  # one frame set: as before
    assert "frame_set_groups" not in json.loads(out)
    assert all("frame_set" not in r for t in json.loads(out)["tables"] for r in t["rows"])


def test_runs_on_other_prompt_sets_are_marked(runs, synth_root, capsys, tmp_path):
    from importlib.resources import files

    prompts = json.loads((files("lightemma") / "prompts" / "lightemma-v1.json").read_text(encoding="utf-8"))
    prompts["name"] = "lab-v2"
    (tmp_path / "p.json").write_text(json.dumps(prompts), encoding="utf-8")
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert (
            main(
                [
                    "run",
                    "--model",
                    "baseline:constant",
                    "--dataroot",
                    str(synth_root),
                    "--version",
                    "v1.0-mini",
                    "--split",
                    "all",
                    "--out",
                    str(tmp_path / "runs"),
                    "--prompt-set",
                    str(tmp_path / "p.json"),
                ]
            )
            == 0
        )
    rc, out, err = _evaluate(capsys, runs / "all", tmp_path / "runs")
    assert rc == 0, err
    notes = [line for line in out.splitlines() if line.startswith("Runs differ in prompt sets:")]
    assert notes and "lab-v2" in notes[0] and "lightemma-v1" in notes[0]
    assert "Baseline (constant actions)" in notes[0] and "Baseline (constant velocity)" in notes[0]
    rc, out, err = _evaluate(capsys, runs / "all", runs / "subset")
    assert "Runs differ in prompt sets" not in out
