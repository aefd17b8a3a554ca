"""A project directory: its dock and sea sessions, which must describe the same ship."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from shipstar.config._session import SessionConfig, load_session
from shipstar.config._ship import ShipConfig
from shipstar.errors import ShipstarError


@dataclass(frozen=True, eq=False)
class ProjectConfig:
    """A directory's dock and sea sessions (they must describe the same ship)."""

    directory: Path
    dock: SessionConfig
    sea: SessionConfig

    @property
    def ship(self) -> ShipConfig:
        return self.dock.ship


def load_project(directory) -> ProjectConfig:
    """Read ``dock.toml`` and ``sea.toml`` of a directory (and the files they name)."""
    d = Path(directory)
    if not d.is_dir():
        raise ShipstarError(f"configuration directory {d} does not exist (write one with "
                            "'shipstar demo --write-config DIR')")
    dock, sea = load_session(d / "dock.toml"), load_session(d / "sea.toml")
    if dock.kind != "dock" or sea.kind != "sea":
        raise ShipstarError(f"{d}: dock.toml must be kind = \"dock\" and sea.toml kind = \"sea\"")
    if [s.name for s in dock.ship.sensors] != [s.name for s in sea.ship.sensors]:
        raise ShipstarError(f"{d}: dock.toml and sea.toml describe different sensors")
    return ProjectConfig(d, dock, sea)
