"""The package's layout: no new module shares its basename with another (issue 31 renames the old twins)."""

from collections import Counter
from pathlib import Path

import lightemma

# Twins that predate this rule, each to be renamed by the restructuring (issue 31); the list only shrinks.
KNOWN_TWINS = {"ablations", "base", "demo", "kinematics", "models", "render", "scenarios", "writer"}


def test_no_new_module_shares_a_basename_with_another():
    root = Path(lightemma.__file__).parent
    names = Counter(p.stem for p in root.rglob("*.py") if p.stem != "__init__")
    twins = {name for name, count in names.items() if count > 1}
    assert twins - KNOWN_TWINS == set(), f"modules sharing a basename: {sorted(twins - KNOWN_TWINS)}"
    assert KNOWN_TWINS - twins == set(), f"renamed, drop from KNOWN_TWINS: {sorted(KNOWN_TWINS - twins)}"
