"""The evaluation sidecar (frames.columns.npz): the same numbers as frames.jsonl, rebuilt whenever frames.jsonl changes."""

import json
import os

import numpy as np
import pytest

from lightemma.cli import main
from lightemma.evaluation import evaluate_runs
from lightemma.evaluation.loading import load_run
from lightemma.evaluation.rescore import ParseDefinition
from lightemma.evaluation.synthetic import write_synthetic_run
from lightemma.runs import columns
from lightemma.runs.columns import SIDECAR_FILE
from lightemma.runs.importer import import_reference
from tests.support.reference_fixtures import write_results

FIELDS = (
    "frame_ids",
    "trajectory",
    "gt_positions",
    "status",
    "first_status",
    "seconds",
    "input_tokens",
    "output_tokens",
    "cost_cents",
    "cached_input_tokens",
    "history_actions",
    "actions",
    "failure",
    "scene_index",
    "scene_names",
    "caught_implausible",
    "corrupt_lines",
    "truncated_tail",
    "duplicates",
    "bad_records",
    "foreign_records",
    "foreign_example",
    "frame_set_size",
    "warnings",
)


def assert_same(a, b):
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            assert (x is None) == (y is None), name
            if x is not None:
                assert x.dtype == y.dtype and x.shape == y.shape, name
                np.testing.assert_array_equal(x, y, err_msg=name)  # NaN equal to NaN, every bit of every number
        else:
            assert x == y, name


def _messy_run(tmp_path):
    """A run with every kind of record evaluation treats apart: duplicates, bad ground truth, foreign frames, …"""
    run_dir = write_synthetic_run(tmp_path, "m/b", 120, seed=2, finished=False, frames_per_scene=13)
    lines = (run_dir / "frames.jsonl").read_text().splitlines()
    recs = [json.loads(line) for line in lines]
    extra = []
    for i, change in enumerate(
        [
            {"status": "ok", "failure": None},  # a later record of frame 3 (last wins)
            {"gt_positions": recs[10]["gt_positions"][:5]},  # no usable ground truth
            {"frame_id": "scene-0999/7", "scene_name": "scene-0999"},  # not in the frame set
            {"gt_positions": [[0, "x"]] * 6},
            {"trajectory": None},  # integrated from its actions
            {"actions": [[99, 0]] * 6, "trajectory": None},  # implausible
        ]
    ):
        extra.append(json.dumps({**recs[3 + 3 * i], **change}))
    nameless = dict(recs[30])
    del nameless["scene_name"]
    extra.append(json.dumps({**nameless, "frame_id": "scene-0000/99"}))
    lines[20] = "not json"
    ids = sorted({r["frame_id"] for r in recs} | {"scene-0000/99"})
    (run_dir / "frame_ids.txt").write_text("\n".join(ids) + "\n")
    (run_dir / "frames.jsonl").write_text("\n".join(lines + extra) + "\n" + '{"frame_id": "trunc')
    return run_dir


@pytest.mark.parametrize("details", [False, True])
def test_the_sidecar_gives_the_numbers_of_frames_jsonl(tmp_path, monkeypatch, details):
    run_dir = _messy_run(tmp_path)
    truth = load_run(run_dir, details=details, sidecar=False)
    assert not (run_dir / SIDECAR_FILE).exists()  # sidecar=False writes nothing
    assert truth.duplicates == 4 and truth.foreign_records == 1 and truth.bad_records == 2 and truth.corrupt_lines == 1
    first = load_run(run_dir, details=details)  # reads frames.jsonl, writes the sidecar
    assert (run_dir / SIDECAR_FILE).is_file()
    assert_same(first, truth)

    def no_jsonl(*args, **kw):
        raise AssertionError("frames.jsonl was read although the sidecar is current")

    monkeypatch.setattr(columns, "iter_records", no_jsonl)
    assert_same(load_run(run_dir, details=details), truth)


def test_a_changed_frames_jsonl_makes_the_sidecar_stale_and_it_is_rebuilt(tmp_path):
    run_dir = write_synthetic_run(tmp_path, "m/a", 60, seed=1)
    frames = run_dir / "frames.jsonl"
    assert len(load_run(run_dir)) == 60 and (run_dir / SIDECAR_FILE).is_file()
    # an appended record (a resumed session) is seen at once
    record = json.loads(frames.read_text().splitlines()[0])
    with open(frames, "a") as fh:
        fh.write(json.dumps({**record, "frame_id": "scene-0100/7", "scene_name": "scene-0100"}) + "\n")
    data = load_run(run_dir)
    assert len(data) == 61 and data.frame_ids[-1] == "scene-0100/7"
    assert_same(data, load_run(run_dir, sidecar=False))
    # an edit near the end that keeps the size and the mtime (a number changed in place) is seen too
    stat = frames.stat()
    head, last = frames.read_text().rstrip("\n").rsplit("\n", 1)
    old = f'"seconds": {record["seconds"]!r}'
    new = '"seconds": ' + "7.5".ljust(len(repr(record["seconds"])), "0")
    assert old in last and len(last) < columns._TAIL_BYTES
    frames.write_text(head + "\n" + last.replace(old, new) + "\n")
    os.utime(frames, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert frames.stat().st_size == stat.st_size and frames.stat().st_mtime_ns == stat.st_mtime_ns
    assert load_run(run_dir).seconds[-1] == 7.5


def test_a_killed_writers_temporary_is_removed_at_the_next_write(tmp_path):
    run_dir = write_synthetic_run(tmp_path, "m/a", 20, seed=1)
    old = run_dir / f".{SIDECAR_FILE}.abc123.tmp"
    fresh = run_dir / f".{SIDECAR_FILE}.def456.tmp"  # maybe another process writing right now: kept
    old.write_bytes(b"half")
    fresh.write_bytes(b"half")
    os.utime(old, (1_000_000_000, 1_000_000_000))
    load_run(run_dir)
    assert not old.exists() and fresh.exists() and (run_dir / SIDECAR_FILE).is_file()


def test_a_damaged_or_foreign_sidecar_is_never_trusted(tmp_path):
    run_dir = write_synthetic_run(tmp_path, "m/a", 40, seed=1)
    truth = load_run(run_dir, sidecar=False)
    sidecar = run_dir / SIDECAR_FILE
    sidecar.write_bytes(b"PK\x03\x04 not a zip")
    assert_same(load_run(run_dir), truth)
    assert_same(load_run(run_dir), truth)  # rebuilt, and now read
    other = write_synthetic_run(tmp_path, "m/c", 40, seed=9)
    load_run(other)
    os.replace(other / SIDECAR_FILE, sidecar)  # another run's sidecar, copied in
    assert_same(load_run(run_dir), truth)


def test_an_imported_run_comes_with_its_sidecar_and_evaluates_the_same(tmp_path):
    write_results(tmp_path / "results")
    results = import_reference([tmp_path / "results"], tmp_path / "runs")
    for result in results:
        assert (result.run_dir / SIDECAR_FILE).is_file()  # written from the records in hand, before the rename
        from_import = columns.read_sidecar(result.run_dir, columns.source_key(result.run_dir))
        assert from_import is not None
        assert_same(load_run(result.run_dir), load_run(result.run_dir, sidecar=False))
    # a re-scoring definition reads the answers from frames.jsonl, never the sidecar
    strict = ParseDefinition(mode="strict")
    ev = evaluate_runs([tmp_path / "runs"], parse=strict)
    assert ev.accuracy_rows()


def test_a_session_of_lightemma_run_ends_by_writing_the_sidecar(tmp_path, synth_root):
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
                "--output",
                str(tmp_path / "runs"),
                "--no-progress",
            ]
        )
        == 0
    )
    (run_dir,) = [p.parent for p in (tmp_path / "runs").rglob("frames.jsonl")]
    assert (run_dir / SIDECAR_FILE).is_file()
    assert columns.read_sidecar(run_dir, columns.source_key(run_dir)) is not None  # current
    assert_same(load_run(run_dir), load_run(run_dir, sidecar=False))
