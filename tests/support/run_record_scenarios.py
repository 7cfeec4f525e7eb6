"""Runs whose written files pin the frame-record format (tests/golden/run_records.json).

Every writer of ``frames.jsonl`` runs once here: the chain over a baseline, over the loopback OpenAI-compatible
server (with the response cache, a conversation chain and a resume), over the loopback batch server, and the
reference importer. :func:`scenarios` returns each run's ``frames.jsonl`` (the records in frame order) and its
manifest as text, with what changes from one run to the next replaced by placeholders (times, ids, paths, ports —
:func:`run_config_scenarios.normalized` for the manifest), so the same runs give the same bytes before and after a
change to how the records are built. ``records`` returns the records themselves, for the schema check.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from tests.support.fake_batch import FakeBatchServer
from tests.support.fake_openai import FakeOpenAIServer
from tests.support.memframes import make_frames
from tests.support.reference_fixtures import write_results
from tests.support.run_config_scenarios import FAST, normalized

GOLDEN = Path(__file__).resolve().parents[1] / "golden" / "run_records.json"
# times, and the count of transient-failure retries (a loopback server on a loaded machine may time out once)
_VOLATILE_NUMBERS = ("seconds", "call_seconds", "wall_seconds", "retries", "imported_at")


def _is_volatile(key: str) -> bool:
    return key in _VOLATILE_NUMBERS or "turnaround" in key


def _volatile(value: Any) -> Any:
    """``value`` with every time and retry count (:func:`_is_volatile`) replaced by a placeholder, key order kept."""
    if isinstance(value, dict):
        return {k: ("<volatile>" if _is_volatile(k) and v is not None else _volatile(v)) for k, v in value.items()}
    if isinstance(value, list):
        return [_volatile(v) for v in value]
    return value


def normalized_frames(run_dir: Path, tmp: Path) -> str:
    """``frames.jsonl`` of ``run_dir``: its lines sorted by frame id (concurrent frames finish in any order), each
    re-encoded as the writer encodes it (key order kept) with times, paths and the port as placeholders."""
    from lightemma.runs.store import FRAMES_FILE

    lines = (run_dir / FRAMES_FILE).read_text().splitlines()
    records = sorted((json.loads(line) for line in lines), key=lambda r: r["frame_id"])
    text = "\n".join(json.dumps(_volatile(r), ensure_ascii=False) for r in records)
    text = text.replace(str(tmp.resolve()), "<tmp>").replace(str(tmp), "<tmp>")
    return re.sub(r"\d{8}T\d{6}Z-[0-9a-f]{6}", "<run_id>", text)


def _port(url: str) -> int:
    return int(url.split("://", 1)[1].split("/", 1)[0].rsplit(":", 1)[1])


def _both(run_dir: Path, tmp: Path, synth_root: Path, ports: list[int]) -> dict[str, str]:
    from lightemma.runs.store import read_manifest

    out = {"frames": normalized_frames(run_dir, tmp), "manifest": normalized(_volatile(read_manifest(run_dir)), tmp)}
    for key, text in out.items():
        text = text.replace(str(synth_root.resolve()), "<synth>").replace(str(synth_root), "<synth>")
        for port in ports:
            text = text.replace(f":{port}", ":<port>")
        out[key] = text
    return out


def run_dirs(tmp: Path, synth_root: Path, ports: list[int] | None = None) -> dict[str, Path]:
    """Every scenario's run directory (``tmp``: an empty directory); the loopback servers' ports are appended to
    ``ports``."""
    import os

    import lightemma.backends.batch as batch_module
    from lightemma.pipeline import resume, run
    from lightemma.runs.importer import import_reference
    from lightemma.runs.store import FRAMES_FILE

    out: dict[str, Path] = {}
    out["baseline_cv"] = run(
        "baseline:cv", dataroot=synth_root, version="v1.0-mini", split="all", limit=3, output=tmp / "a", progress=False
    ).run_dir
    frames = make_frames(tmp, 3)
    ports = ports if ports is not None else []
    with FakeOpenAIServer() as server:
        ports.append(_port(server.url))
        r = run(
            "openai/gpt-4o",
            frames=frames,
            api_base=server.url,
            output=tmp / "c",
            cache=True,
            concurrency=1,
            chain="conversation",
            **FAST,
        )
        path = r.run_dir / FRAMES_FILE
        path.write_bytes(b"".join(path.read_bytes().splitlines(keepends=True)[:1]))
        resume(r.run_dir, frames=frames, api_base=server.url, cache=True, concurrency=1, progress=False)
        out["api_conversation_resumed"] = r.run_dir
        out["api_price"] = run(
            "openai/test-model",
            frames=frames,
            api_base=server.url,
            output=tmp / "d",
            price=(1.5, 6.0),
            concurrency=1,
            **FAST,
        ).run_dir
    idle = batch_module.IDLE_SECONDS
    key = os.environ.get("OPENAI_API_KEY")
    batch_module.IDLE_SECONDS = 0.15
    os.environ["OPENAI_API_KEY"] = "sk-test-openai"
    try:
        with FakeBatchServer(steps=2, shuffle=True, seed=7) as server:
            ports.append(_port(server.url))
            out["batch_openai"] = run(
                "openai/gpt-4o",
                dataroot=synth_root,
                version="v1.0-mini",
                split="all",
                sample=3,
                output=tmp / "e",
                batch=True,
                batch_poll=0.01,
                api_base=server.url,
                progress=False,
            ).run_dir
    finally:
        batch_module.IDLE_SECONDS = idle
        if key is None:
            os.environ.pop("OPENAI_API_KEY", None)
        else:
            os.environ["OPENAI_API_KEY"] = key
    write_results(tmp / "results")
    for result in import_reference([tmp / "results"], tmp / "imported", warn=lambda _: None):
        out[f"import_{result.model}"] = result.run_dir
    return out


def scenarios(tmp: Path, synth_root: Path) -> dict[str, dict[str, str]]:
    """Every scenario's normalized ``frames.jsonl`` and manifest (``tmp``: an empty directory)."""
    ports: list[int] = []
    dirs = run_dirs(tmp, synth_root, ports)
    return {name: _both(run_dir, tmp, synth_root, ports) for name, run_dir in dirs.items()}


def records(tmp: Path, synth_root: Path) -> dict[str, list[dict[str, Any]]]:
    """Every scenario's records as written (decoded lines of ``frames.jsonl``)."""
    from lightemma.runs.store import FRAMES_FILE

    return {
        name: [json.loads(line) for line in (run_dir / FRAMES_FILE).read_text().splitlines()]
        for name, run_dir in run_dirs(tmp, synth_root).items()
    }


if (
    __name__ == "__main__"
):  # python -m tests.support.run_record_scenarios: (re)write the golden (from the code as it is)
    import tempfile

    from lightemma.synth import write_dataset

    with tempfile.TemporaryDirectory() as d:
        root = write_dataset(Path(d) / "synth", scenes=2, keyframes=20, image_size=(64, 36), sweeps=False)
        got = scenarios(Path(d) / "runs", root)
    GOLDEN.write_text(json.dumps(got, indent=1, ensure_ascii=False) + "\n")
    print(f"wrote {GOLDEN}: {', '.join(got)}")
