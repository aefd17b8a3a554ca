"""Data flows one way: a stage imports only the stages before it (docs/architecture.md)."""

from __future__ import annotations

import re
from pathlib import Path

import shipstar

#: The stages, bottom first.  A module of stage i may import stages 0..i only.
ORDER = [
    "units", "errors", "limits", "_atomic", "_arraycache", "_digest", "_signals", "frames",
    "sky", "_cfits", "_fitsio", "camera", "simulate", "extract",
    "attitude", "identify", "_codeid",
    "calibrate", "ship", "errormodel", "pipeline", "live",
    "report", "config", "_demo",
    "cli", "__main__",
]

_IMPORT = re.compile(r"^\s*(?:from|import)\s+shipstar\.(\w+)", re.M)


def _stage(path: Path, root: Path) -> str:
    rel = path.relative_to(root)
    return rel.parts[0].removesuffix(".py") if rel.parts[0] != "__init__.py" else ""


def test_every_stage_is_in_the_order():
    root = Path(shipstar.__file__).parent
    stages = {_stage(p, root) for p in root.rglob("*.py")} - {""}
    assert stages <= set(ORDER), f"stages missing from ORDER: {sorted(stages - set(ORDER))}"


def test_imports_only_go_down():
    root = Path(shipstar.__file__).parent
    rank = {name: i for i, name in enumerate(ORDER)}
    offenders = []
    for path in root.rglob("*.py"):
        src = _stage(path, root)
        if not src:
            continue
        for target in _IMPORT.findall(path.read_text()):
            if target in rank and rank[target] > rank[src]:
                offenders.append(f"{path.relative_to(root)} imports shipstar.{target}")
    assert not offenders, "upward imports:\n" + "\n".join(offenders)
