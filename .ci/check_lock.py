"""Fail unless every installed distribution is pinned in the lock file at the installed version.

Usage: python .ci/check_lock.py constraints.txt

Catches what `pip install -c` alone does not: a dependency that is installed but not in the lock
(added to pyproject.toml without re-running `bash .ci/lock`), or installed at another version.
"""

from __future__ import annotations

import re
import sys
from importlib import metadata

# Installed by the venv or the install itself, never by the lock: the project, and pip.
EXEMPT = {"lightemma", "pip"}


def canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def main(path: str) -> int:
    pins: dict[str, str] = {}
    for line in open(path, encoding="utf-8"):
        m = re.match(r"^([A-Za-z0-9][A-Za-z0-9._-]*)==([^\s;\\]+)", line)
        if m:
            pins[canonical(m.group(1))] = m.group(2)
    problems = []
    for dist in metadata.distributions():
        name = canonical(dist.metadata["Name"])
        if name in EXEMPT:
            continue
        if name not in pins:
            problems.append(f"{name}=={dist.version} is installed but not in {path}")
        elif pins[name] != dist.version:
            problems.append(f"{name} is {dist.version}, {path} pins {pins[name]}")
    for p in sorted(problems):
        print(p)
    if problems:
        print(f"{len(problems)} package(s) differ from the lock: run `bash .ci/lock`, then `bash .ci/run`")
        return 1
    print(f"all installed packages match {path} ({len(pins)} pins)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else "constraints.txt"))
