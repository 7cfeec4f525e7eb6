#!/usr/bin/env bash
# The GPU bench, one command (docs/local.md#gpu-bench): on the GPU machine, after benches/gpu/prepare.sh here,
#   bash benches/gpu/run.sh            # installs benches/gpu/wheels offline, measures, writes $OUT/gpu.json + gpu.md
#   bash benches/gpu/run.sh --tiny     # the same on a CPU with tiny configs, in the current environment (CI runs it)
# PYTHON: the interpreter (default: the first of python3, python, python3.12 that imports torch).
# Stops itself before 8 minutes (install included): no step starts that would not fit, and a watchdog
# ends the bench at its deadline with what it measured already written.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="${OUT:-$here/out}"
export HF_HUB_OFFLINE=1 TRANSFORMERS_OFFLINE=1 LITELLM_LOCAL_MODEL_COST_MAP=True MPLBACKEND=Agg PYTHONUNBUFFERED=1
py="${PYTHON:-python3}"
if [ "${1:-}" = "--tiny" ]; then
  shift
  exec timeout 300 "$py" "$here/bench_gpu.py" --tiny --out "$out/tiny" --deadline 240 "$@"
fi
start=$SECONDS
mkdir -p "$out"
if [ -z "${PYTHON:-}" ]; then  # the interpreter that has the machine's torch
  for candidate in python3 python python3.12; do
    if command -v "$candidate" >/dev/null && "$candidate" -c 'import torch, transformers' 2>/dev/null; then
      py="$candidate"; break
    fi
  done
fi
# lightemma and each wheel whose package the machine lacks, unpacked (a wheel is a zip made to be
# unpacked; no pip, no venv, no network needed) into a folder put first on the path
site="$here/.site"
rm -rf "$site"
"$py" - "$here/wheels" "$site" <<'PY' 2>&1 | tee "$out/install.log"
import glob, sys, zipfile
from importlib import metadata
wheels, site = sorted(glob.glob(f"{sys.argv[1]}/*.whl")), sys.argv[2]
if not wheels:
    sys.exit(f"no wheels in {sys.argv[1]}: run benches/gpu/prepare.sh first and carry benches/gpu/wheels")
print(f"python {sys.version.split()[0]} at {sys.executable}")
for w in wheels:
    name = w.rsplit("/", 1)[1].split("-")[0].replace("_", "-").lower()
    try:
        have = metadata.version(name)
    except metadata.PackageNotFoundError:
        have = None
    if name == "lightemma" or have is None:
        zipfile.ZipFile(w).extractall(site)
        print(f"{name}: unpacked {w.rsplit('/', 1)[1]}")
    else:
        print(f"{name}: present ({have})")
PY
export PYTHONPATH="$site${PYTHONPATH:+:$PYTHONPATH}"
left=$(( 470 - (SECONDS - start) ))
timeout "$left" "$py" "$here/bench_gpu.py" --out "$out" --deadline $(( left - 25 )) "$@"
