"""Fixtures shared by the command-line tests."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def dock(tmp_path_factory):
    """A 0.3 s simulated dock session and A1's true installation file."""
    from shipstar.calibrate.installation import Installation, save_installation
    from shipstar.simulate._session import dock_session, write_session

    root = tmp_path_factory.mktemp("dock")
    spec = dock_session(duration_s=0.3)
    write_session(spec, root / "dock")
    s = spec.sensors[0]
    save_installation(Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor), root / "A1.toml")
    return root
