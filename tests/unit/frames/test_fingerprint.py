"""Frame-set fingerprints (lightemma.frames.fingerprint): recorded by every run and import, derived for older runs,
checked against the run's frame list, refused when edited by hand."""

from __future__ import annotations

import json

import pytest

from lightemma.cli import main
from lightemma.errors import RunStoreError
from lightemma.frames.fingerprint import (
    check_fingerprint,
    describe_fingerprint,
    fingerprint,
    run_fingerprint,
    tokens_hash,
)
from lightemma.runs.store import find_run_dirs, read_frame_ids, read_manifest

IDS = ["scene-0002/bbb", "scene-0001/aaa", "scene-0001/ccc"]


def test_fingerprint_is_order_free_and_names_what_it_covers():
    a = fingerprint(IDS, version="v1.0-mini", split="all", window="reference")
    b = fingerprint(list(reversed(IDS)), version="v1.0-mini", split="all", window="reference")
    assert a == b and a["n_frames"] == 3 and a["id"].startswith("frames:") and len(a["id"]) == len("frames:") + 16
    assert a["tokens"] == tokens_hash(["x/aaa", "y/bbb", "z/ccc"], "reference")  # sample tokens, not scene names
    # every field moves the id: window (and the tokens with it), split, limit, sample, version, one frame fewer
    others = [
        fingerprint(IDS, version="v1.0-mini", split="all", window="full"),
        fingerprint(IDS, version="v1.0-mini", split="mini_val", window="reference"),
        fingerprint(IDS, version="v1.0-mini", split="all", window="reference", limit=3),
        fingerprint(IDS, version="v1.0-mini", split="all", window="reference", sample={"n": 3, "seed": 1}),
        fingerprint(IDS, version="v1.0-trainval", split="all", window="reference"),
        fingerprint(IDS[:2], version="v1.0-mini", split="all", window="reference"),
    ]
    assert len({a["id"], *(o["id"] for o in others)}) == 7
    assert others[0]["tokens"] != a["tokens"]
    assert describe_fingerprint(a) == f"{a['id']} (v1.0-mini, split all, reference window, 3 frames)"


@pytest.mark.parametrize(
    ("field", "value"),
    [("split", "test"), ("n_frames", 4), ("window", "full"), ("limit", 2), ("tokens", "sha256:" + "0" * 64)],
)
def test_a_hand_edited_fingerprint_is_refused(field, value):
    fp = fingerprint(IDS, version="v1.0-mini", split="all", window="reference")
    check_fingerprint(fp, "here")
    with pytest.raises(RunStoreError, match=r"^here\.id: frames:[0-9a-f]{16} does not match its fields"):
        check_fingerprint({**fp, field: value}, "here")


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"format": "lightemma-frames/2"}, r"here\.format: .*another lightemma version"),
        ({"tokens": "md5:abc"}, r"here\.tokens: "),
        ({"id": "abc"}, r"here\.id: 'abc' is not"),
    ],
)
def test_a_fingerprint_of_another_format_is_refused(change, message):
    fp = fingerprint(IDS, version="v1.0-mini", split="all", window="reference")
    with pytest.raises(RunStoreError, match=message):
        check_fingerprint({**fp, **change}, "here")
    with pytest.raises(RunStoreError, match=r"here\.sample: missing"):
        check_fingerprint({k: v for k, v in fp.items() if k != "sample"}, "here")


@pytest.fixture(scope="module")
def runs(synth_root, tmp_path_factory):
    out = tmp_path_factory.mktemp("fp_runs")
    assert (
        main(
            [
                "run",
                "--model",
                "baseline:cv",
                "--dataroot",
                str(synth_root),
                "--version",
                "v1.0-mini",
                "--split",
                "all",
                "--out",
                str(out / "a"),
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "run",
                "--model",
                "baseline:cv",
                "--dataroot",
                str(synth_root),
                "--version",
                "v1.0-mini",
                "--split",
                "all",
                "--limit",
                "5",
                "--out",
                str(out / "b"),
            ]
        )
        == 0
    )
    return find_run_dirs(out / "a")[0], find_run_dirs(out / "b")[0]


def _copy(run_dir, tmp_path):
    import shutil

    dest = tmp_path / "runs" / run_dir.parent.name / run_dir.name
    shutil.copytree(run_dir, dest)
    return dest


def test_every_run_records_its_fingerprint(runs):
    full, limited = runs
    fp = read_manifest(full)["dataset"]["fingerprint"]
    ids = read_frame_ids(full)
    assert fp == fingerprint(ids, version="v1.0-mini", split="all", window="reference") and fp["n_frames"] == 12
    fp5 = read_manifest(limited)["dataset"]["fingerprint"]
    assert fp5["limit"] == 5 and fp5["n_frames"] == 5 and fp5["id"] != fp["id"]
    assert run_fingerprint(full, read_manifest(full), []) == fp


def test_an_older_run_gets_a_derived_fingerprint(runs, tmp_path):
    run = _copy(runs[0], tmp_path)
    manifest = read_manifest(run)
    recorded = manifest["dataset"].pop("fingerprint")
    (run / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")
    derived = run_fingerprint(run, manifest, [])
    assert derived["derived"] is True and derived["from"] == "frame_ids.txt"
    assert {k: v for k, v in derived.items() if k not in ("derived", "from")} == recorded
    (run / "frame_ids.txt").unlink()  # older still: only the records say which frames
    from lightemma.evaluation import load_run

    data = load_run(run)
    again = run_fingerprint(run, manifest, data.frame_ids)
    assert again["from"] == "frames.jsonl" and again["id"] == recorded["id"]


def test_evaluate_refuses_a_hand_edited_fingerprint_in_one_line(runs, tmp_path, capsys):
    run = _copy(runs[0], tmp_path)
    manifest = read_manifest(run)
    manifest["dataset"]["fingerprint"]["split"] = "test"  # a run "on the test split"
    (run / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")
    capsys.readouterr()
    assert main(["evaluate", str(run), "--resamples", "0", "--format", "json"]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    lines = [line for line in err.splitlines() if line.strip()]
    assert (
        len(lines) == 1
        and "manifest.json: dataset.fingerprint.id: " in lines[0]
        and "does not match its fields" in lines[0]
    )


def test_a_fingerprint_that_disagrees_with_the_run_is_refused(runs, tmp_path):
    run = _copy(runs[0], tmp_path)
    manifest = read_manifest(run)
    ids = read_frame_ids(run)
    (run / "frame_ids.txt").write_text("".join(f"{i}\n" for i in ids[:-1]), encoding="utf-8")
    with pytest.raises(
        RunStoreError,
        match=r"manifest\.json: dataset\.fingerprint\.tokens: does not match the 11 frames of .*frame_ids\.txt",
    ):
        run_fingerprint(run, manifest, [])
    # a consistent fingerprint of other settings than the manifest's dataset
    other = fingerprint(ids, version="v1.0-mini", split="mini_val", window="reference")
    manifest["dataset"]["fingerprint"] = other
    with pytest.raises(
        RunStoreError, match=r"dataset\.fingerprint\.split: 'mini_val' disagrees with dataset\.split 'all'"
    ):
        run_fingerprint(run, manifest, [])


def test_imported_runs_record_a_derived_fingerprint(tmp_path):
    from lightemma.runs.importer import import_reference
    from tests.support.reference_fixtures import write_results

    write_results(tmp_path / "results")
    result = import_reference([tmp_path / "results" / "gpt-4o"], tmp_path / "runs")
    run_dir = result[0].run_dir
    manifest = read_manifest(run_dir)
    fp = manifest["dataset"]["fingerprint"]
    assert fp["derived"] is True and fp["from"] == "import" and fp["version"] is None and fp["window"] == "reference"
    from lightemma.evaluation import load_run

    data = load_run(run_dir)
    assert fp["n_frames"] == len(data.frame_ids) and fp["tokens"] == tokens_hash(data.frame_ids, "reference")
    assert run_fingerprint(run_dir, manifest, data.frame_ids) == fp
