#!/usr/bin/env bash
# The GPU bench, one command (docs/local.md#gpu-bench): on the GPU machine, after benches/gpu/prepare.sh here,
#   bash benches/gpu/run.sh            # installs benches/gpu/wheels offline, measures, writes $OUT/gpu.json + gpu.md
#   bash benches/gpu/run.sh --tiny     # the same on a CPU with tiny configs, in the current environment (CI runs it)
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
# a venv over the machine's own torch and transformers; lightemma and what is missing, from the wheels
venv="$here/.venv"
"$py" -m venv --system-site-packages "$venv"
"$venv/bin/python" - "$here/wheels" <<'PY' 2>&1 | tee "$out/install.log"
import glob, subprocess, sys
from importlib import metadata
wheels = sorted(glob.glob(f"{sys.argv[1]}/*.whl"))
todo = []
for w in wheels:
    name = w.rsplit("/", 1)[1].split("-")[0].replace("_", "-").lower()
    try:
        have = metadata.version(name)
    except metadata.PackageNotFoundError:
        have = None
    if name == "lightemma" or have is None:
        todo.append(w)
    print(f"{name}: {'installing ' + w.rsplit('/', 1)[1] if w in todo else 'present (' + have + ')'}")
subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-index", "--no-deps", *todo], check=True)
PY
left=$(( 470 - (SECONDS - start) ))
timeout "$left" "$venv/bin/python" "$here/bench_gpu.py" --out "$out" --deadline $(( left - 25 )) "$@"
