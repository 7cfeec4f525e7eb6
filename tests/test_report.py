"""`lightemma report`: one folder with an index linking tables and figures that exist and show something."""

from __future__ import annotations

import os
import re

os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np
import pytest
from PIL import Image

from lightemma.cli import main
from lightemma.evaluation.synthetic import write_synthetic_run
from lightemma.report import write_report


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    runs = tmp_path_factory.mktemp("runs")
    write_synthetic_run(runs, "openai/gpt-4o", 60, seed=1, noise=0.3)
    write_synthetic_run(runs, "gemini/gemini-2.0-flash", 60, seed=2, noise=0.8)
    write_synthetic_run(runs, "baseline:cv", 60, seed=3, noise=1.5, manifest={"dataset": {"dataroot": str(runs / "nowhere"), "version": "v1.0-mini", "split": "all"}})
    out = tmp_path_factory.mktemp("report")
    index = write_report([runs], out, top=1, common=True)
    return out, index, index.read_text()


def test_index_links_only_files_that_exist(report):
    out, index, text = report
    links = re.findall(r"\]\(([^)]+)\)", text)
    assert len(links) >= 12
    for link in links:
        assert (out / link).is_file(), link
    for name in ("efficiency", "accuracy_lightemma", "accuracy_stp3", "accuracy_uniad"):
        assert (out / "tables" / f"{name}.csv").is_file() and (out / "tables" / f"{name}.tex").is_file()
    assert (out / "tables" / "evaluation.json").is_file()


def test_index_has_tables_scenarios_and_pictures(report):
    out, index, text = report
    assert "| GPT-4o |" in text and "| Gemini-2.0-Flash |" in text and "| GPT-4o (paper) |" in text
    assert "frames valid for every run" in text
    assert "### ADE avg by scenario tag" in text and "| braking |" in text
    assert "History bias" in text
    assert "models disagree by" in text and "worst `braking` frame" in text
    # the dataset named in a manifest is not there: said once, pictures still drawn (bird's-eye only)
    assert "pictures have no camera view" in text
    grids = sorted((out / "figures" / "frames").glob("*_grid.png"))
    assert grids


def test_report_figures_are_not_blank(report):
    out, index, text = report
    for png in [out / "figures" / "bubble.png", out / "figures" / "history_bias.png", *sorted((out / "figures" / "frames").glob("*.png"))[:3]]:
        img = np.asarray(Image.open(png).convert("RGB"))
        assert img.shape[0] > 200 and img.shape[1] > 300
        assert len(np.unique(img.reshape(-1, 3), axis=0)) > 20, png
        assert (png.with_suffix(".svg")).stat().st_size > 1000


def test_cli_report_and_its_errors(tmp_path, capsys):
    runs = tmp_path / "runs"
    write_synthetic_run(runs, "openai/gpt-4o", 12)
    assert main(["report", str(runs), "--out", str(tmp_path / "rep"), "--no-pictures", "--no-paper"]) == 0
    assert f"report written to {tmp_path / 'rep' / 'index.md'}" in capsys.readouterr().out
    text = (tmp_path / "rep" / "index.md").read_text()
    assert "(paper)" not in text and "figures/frames" not in text
    assert main(["report", str(tmp_path / "missing"), "--out", str(tmp_path / "rep2")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("lightemma report: error:") and "does not exist" in err and "\n" not in err
