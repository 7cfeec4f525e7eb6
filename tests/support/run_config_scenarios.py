"""Runs whose manifests pin the run settings a manifest records (tests/golden/run_config_manifests.json).

Each scenario runs lightemma with many settings away from their defaults; :func:`normalized` keeps the manifest's
bytes apart from what changes from one run to the next (times, ids, paths, ports, versions), so that the same run
gives the same text before and after a change to how the runner holds its settings.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from tests.support.fake_openai import FakeOpenAIServer
from tests.support.memframes import make_frames

GOLDEN = Path(__file__).resolve().parents[1] / "golden" / "run_config_manifests.json"
FAST = dict(backoff_base=0.01, backoff_cap=0.05, timeout=5.0, progress=False)
VOLATILE = ("run_id", "started_at", "finished_at", "git_revision", "python", "lightemma_version")


def normalized(manifest: dict[str, Any], tmp: Path, port: int | None = None) -> str:
    """The manifest as JSON text (key order kept), with times, ids, paths and the port replaced by placeholders."""
    out = {k: ("<volatile>" if k in VOLATILE and manifest.get(k) is not None else v) for k, v in manifest.items()}
    sessions = []
    for session in out.get("sessions", []):
        sessions.append(
            {
                k: ("<volatile>" if k in ("started_at", "finished_at", "pid", "wall_seconds") else v)
                for k, v in session.items()
            }
        )
    if "sessions" in out:
        out["sessions"] = sessions
    if isinstance(out.get("summary"), dict):
        out["summary"] = {
            k: ("<volatile>" if "second" in k or k in ("wall_seconds",) else v) for k, v in out["summary"].items()
        }
    text = json.dumps(out, indent=1, ensure_ascii=False)
    text = text.replace(str(tmp.resolve()), "<tmp>").replace(str(tmp), "<tmp>")
    if port is not None:
        text = text.replace(f":{port}", ":<port>")
    return re.sub(r"\d{8}T\d{6}Z-[0-9a-f]{6}", "<run_id>", text)


def scenarios(tmp: Path, synth_root: Path) -> dict[str, str]:
    """Every scenario's normalized manifest (``tmp``: an empty directory)."""
    from lightemma.pipeline import resume, run
    from lightemma.runs.store import FRAMES_FILE, read_manifest

    out: dict[str, str] = {}
    synth = str(synth_root)
    r = run(
        "baseline:cv",
        dataroot=synth_root,
        version="v1.0-mini",
        split="all",
        limit=3,
        output=tmp / "a",
        name="golden a",
        progress=False,
    )
    out["baseline_dataroot_limit"] = normalized(read_manifest(r.run_dir), tmp).replace(synth, "<synth>")
    r = run(
        "baseline:oracle",
        dataroot=synth_root,
        version="v1.0-mini",
        scenes=None,
        window="full",
        sample=4,
        sample_seed=7,
        speed_range=None,
        max_abs_curvature=None,
        integrate_method="midpoint",
        reask="chain",
        max_attempts=2,
        concurrency=3,
        on_bad_record="error",
        output=tmp / "b",
        progress=False,
    )
    out["baseline_sample_no_limits"] = normalized(read_manifest(r.run_dir), tmp).replace(synth, "<synth>")

    frames = make_frames(tmp, 3)
    with FakeOpenAIServer() as server:
        port = int(server.url.rsplit(":", 1)[1].split("/")[0])
        base = server.url.replace("http://", "http://user:secret@")
        r = run(
            "openai/gpt-4o",
            frames=frames,
            api_base=base,
            output=tmp / "c",
            cache=True,
            rpm=600,
            tpm=1e6,
            concurrency=2,
            temperature=0.5,
            max_tokens=300,
            max_retries=3,
            max_cost_cents=1000,
            transport="direct",
            chain="conversation",
            speed_range=(-5, 40),
            max_abs_curvature=0.5,
            **FAST,
        )
        out["api_cache_limits"] = normalized(read_manifest(r.run_dir), tmp, port)
        path = r.run_dir / FRAMES_FILE
        path.write_bytes(b"".join(path.read_bytes().splitlines(keepends=True)[:1]))
        resume(r.run_dir, frames=frames, api_base=base, cache=True, timeout=7, rpm=300, concurrency=1, progress=False)
        out["api_cache_limits_resumed"] = normalized(read_manifest(r.run_dir), tmp, port)
        r = run(
            "openai/test-model",
            frames=frames,
            api_base=server.url,
            output=tmp / "d",
            cache=str(tmp / "my.sqlite"),
            inputs="no-image",
            answer_format="text",
            price=(1.5, 6.0),
            gpus=2,
            name="golden d",
            **FAST,
        )
        out["api_price_gpus_cache_path"] = normalized(read_manifest(r.run_dir), tmp, port)
    return out


if (
    __name__ == "__main__"
):  # python -m tests.support.run_config_scenarios: (re)write the golden (from the code as it is)
    import tempfile

    from lightemma.synth import write_dataset

    with tempfile.TemporaryDirectory() as d:
        root = write_dataset(Path(d) / "synth", scenes=2, keyframes=20, image_size=(64, 36), sweeps=False)
        got = scenarios(Path(d) / "runs", root)
    GOLDEN.write_text(json.dumps(got, indent=1, ensure_ascii=False) + "\n")
    print(f"wrote {GOLDEN}: {', '.join(got)}")
