#!/usr/bin/env bash
# Build here what benches/gpu/run.sh needs on the GPU machine (Python 3.12, torch 2.11, transformers 5.17,
# no network) into benches/gpu/wheels/ (git-ignored; < 64 MiB, the device's transfer limit):
#   * the lightemma wheel: stable ABI (abi3, CPython >= 3.11) — pyo3 0.30's abi3-py311 feature with
#     rust-numpy 0.30 builds and imports (checked below by installing it into a CPython 3.12 venv);
#     LIGHTEMMA_WHEEL=cp312 builds a CPython 3.12 wheel instead, with the interpreter $PYTHON312
#     (default: python3.12 on the PATH, else pyenv's 3.12);
#   * the wheels the bench imports that a torch + transformers machine may lack, for CPython 3.12 on
#     manylinux x86_64, at the lock's versions (torchvision: the release built for torch 2.11).
# run.sh installs, offline, only those the machine does not have. Then, with the device tool:
#   run(command="bash benches/gpu/run.sh", carry=["benches/gpu/wheels"], timeout_s=540)
set -euo pipefail
cd "$(dirname "$0")/../.."
dest=benches/gpu/wheels
rm -rf "$dest" && mkdir -p "$dest"
py312="${PYTHON312:-$(command -v python3.12 || true)}"
if ! { [ -n "$py312" ] && "$py312" -c '' 2>/dev/null; } && command -v pyenv >/dev/null; then  # a pyenv shim may not run
  py312="$(pyenv root)/versions/$(pyenv versions --bare | grep -E '^3\.12' | tail -1)/bin/python3.12"
fi
[ -x "$py312" ] || { echo "prepare.sh: no CPython 3.12 found: set PYTHON312=/path/to/python3.12"; exit 1; }

echo "== the lightemma wheel"
if [ "${LIGHTEMMA_WHEEL:-abi3}" = abi3 ]; then
  maturin build --release --features pyo3/abi3-py311 --out "$dest" --quiet
else
  maturin build --release --interpreter "$py312" --out "$dest" --quiet
fi

echo "== bench dependencies for CPython 3.12 (no dependencies of theirs: run.sh installs only what is missing)"
pin() { grep -iE "^$1==" constraints.txt | head -1; }
python3 -m pip download --quiet --disable-pip-version-check --only-binary=:all: --no-deps -d "$dest" \
  --python-version 3.12 --implementation cp --abi cp312 --abi abi3 --abi none \
  --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 --platform any \
  "$(pin scipy)" "$(pin pillow)" "$(pin filelock)" "$(pin tqdm)" "$(pin orjson)" "torchvision==0.26.0"

echo "== check: the lightemma wheel installs and imports on CPython 3.12"
check="$(mktemp -d)"
trap 'rm -rf "$check"' EXIT
"$py312" -m venv "$check/venv"
"$check/venv/bin/python" -m pip install --quiet --disable-pip-version-check --no-index --find-links "$dest" \
  "$dest"/lightemma-*.whl "numpy$(pin numpy | sed 's/^numpy//')" 2>/dev/null \
  || "$check/venv/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps "$dest"/lightemma-*.whl numpy
"$check/venv/bin/python" -c "
import numpy as np, lightemma._core as core, lightemma
print('lightemma', lightemma.__version__ if hasattr(lightemma, '__version__') else '', 'imports on', __import__('sys').version.split()[0], 'numpy', np.__version__)
"
du -ch "$dest"/*.whl | tail -1
total=$(du -cb "$dest"/*.whl | tail -1 | cut -f1)
[ "$total" -lt $((64 * 1024 * 1024)) ] || { echo "prepare.sh: $dest is $total bytes, over the 64 MiB the device takes"; exit 1; }
ls -1 "$dest"
