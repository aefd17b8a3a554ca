"""Shared fixtures: cameras and their star databases (built once per session, cached)."""

from __future__ import annotations

import pytest

from shipstar.camera import camera_preset
from shipstar.identify import build_database


@pytest.fixture(scope="session")
def cam12():
    """Seed 004's sensor: 12 x 12 deg, 512 x 512 px, no distortion."""
    return camera_preset("seed004")


@pytest.fixture(scope="session")
def db12(cam12):
    return build_database(cam12)


@pytest.fixture(scope="session")
def cam_a1():
    """Sensor A1 (seed 000): 8.6 deg, 1024 x 1024 px."""
    return camera_preset("A1")


@pytest.fixture(scope="session")
def db_a1(cam_a1):
    return build_database(cam_a1)
