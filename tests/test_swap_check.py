"""The swap check's frames solved once per camera model.

Two sensors of the same camera model (a ship's pair of identical star sensors): a frame's
attitude in the horizontal frame does not depend on which sensor's installation it is
processed with, so the check solves each frame once and applies both installations.  The
premise is tested against independent solves, and the verdicts (right way round: none;
folders swapped: the one-line message) with half the solves.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from shipstar.calibrate.installation import Installation
from shipstar.camera import camera_preset
from shipstar.pipeline import PipelineOptions, SensorConfig, Track, WeatherTable
from shipstar.pipeline._sources import FitsDirectorySource


@pytest.fixture(scope="module")
def twins(tmp_path_factory):
    """0.5 s of a sea session whose two sensors are both camera A1 (installations as the seed's)."""
    from shipstar.simulate._session import sea_session, write_session

    root = tmp_path_factory.mktemp("twins")
    spec = sea_session(duration_s=0.5)
    cam = camera_preset("A1")
    spec = spec.replace(sensors=tuple(replace(s, camera=cam) for s in spec.sensors))
    write_session(spec, root)
    configs = [SensorConfig(s.name, cam, Installation.from_matrix(s.name, cam.name, s.C_deck_from_sensor))
               for s in spec.sensors]
    return root, configs, Track.read_csv(root / "track.csv"), WeatherTable.read_csv(root / "weather.csv")


def _count_solves(monkeypatch):
    from shipstar.pipeline import _sensor

    calls = []
    original = _sensor.SensorProcessor.process

    def counted(self, frame, index, t_s, **kw):
        calls.append((self.config.name, frame.label))
        return original(self, frame, index, t_s, **kw)

    monkeypatch.setattr(_sensor.SensorProcessor, "process", counted)
    return calls


def test_a_frame_solved_as_either_twin_has_the_same_horizontal_attitude(twins):
    from shipstar.pipeline._sensor import SensorProcessor

    root, configs, track, weather = twins
    frame = FitsDirectorySource("A2", root / "A2").piece(0, 1).load()[0]
    options = PipelineOptions()
    a = SensorProcessor(configs[0], track, weather, options).process(frame, 0, 0.0)
    b = SensorProcessor(configs[1], track, weather, options).process(frame, 0, 0.0)
    assert a.solved and b.solved
    np.testing.assert_array_equal(a.horizontal.C_hor_from_sensor, b.horizontal.C_hor_from_sensor)


def test_twins_are_checked_with_one_solve_per_frame(twins, monkeypatch):
    from shipstar.pipeline._integrity import swap_check

    root, configs, track, weather = twins
    options = PipelineOptions()
    right = [FitsDirectorySource(c.name, root / c.name) for c in configs]
    calls = _count_solves(monkeypatch)
    assert swap_check(configs, right, track, weather, options) is None
    assert sorted(calls) == [("A1", "A1_00000.fits"), ("A1", "A2_00000.fits")]      # 2 solves, not 4
    calls.clear()
    swapped = [FitsDirectorySource("A1", root / "A2"), FitsDirectorySource("A2", root / "A1")]
    message = swap_check(configs, swapped, track, weather, options)
    assert message is not None and message.startswith("sensor folders look swapped: A1's frames fit A2's")
    assert len(calls) == 2
