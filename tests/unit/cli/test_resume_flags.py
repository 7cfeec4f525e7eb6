"""`lightemma run --resume RUN --batch-poll S` names the real reason it is refused.

It said "--batch-poll goes with --batch", and adding --batch was then refused in its turn ("--resume takes the
run's mode … drop --batch"): a resume takes every setting, --batch-poll included, from the run's manifest.
"""

from __future__ import annotations

import lightemma
from lightemma.cli import main


def test_resume_with_batch_poll_says_the_manifest_decides(synth_root, tmp_path, capsys) -> None:
    run_dir = lightemma.run(
        "baseline:cv", dataroot=synth_root, version="v1.0-mini", output=tmp_path, limit=2, progress=False
    ).run_dir
    capsys.readouterr()
    assert main(["run", "--resume", str(run_dir), "--batch-poll", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err == "lightemma run: error: --resume takes every setting from the run's manifest; drop --batch-poll"
    # without --resume the pairing rule still holds
    assert main(["run", "--model", "baseline:cv", "--dataroot", str(synth_root), "--batch-poll", "1"]) == 2
    assert capsys.readouterr().err.strip() == "lightemma run: error: --batch-poll goes with --batch"
