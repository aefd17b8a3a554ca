"""The header cross-check of the frames' name cards: each card against what it names.

``SENSOR`` names the sensor and ``INSTRUME`` the camera.  The check compared "SENSOR, else
INSTRUME" with "the sensor's name or the camera's", so a frame whose SENSOR matched was
never compared with the camera given: sensor A1's frames processed with camera A2's model
(0.3 deg off) or calibrated as sensor A2 went through without a word.  Cards that are
absent are not compared; commands with only a camera (``solve``, ``calibrate
intrinsics``) compare the cards present with the camera's name, at most one line a frame.
"""

from __future__ import annotations

import pytest

from shipstar._fitsio import FitsFrameInfo
from shipstar.errors import ShipstarError
from shipstar.pipeline._header_check import TRUST_HINT, HeaderCheck

JD1, JD2 = 2461000.5, 0.25


def _info(sensor: str = "", instrume: str = "", name: str = "A1_00000.fits") -> FitsFrameInfo:
    return FitsFrameInfo(name, (64, 64), JD1, JD2, "DATE-AVG", "", "start", 0.01, instrume, sensor, "")


def _keys(check, info) -> list:
    return [c.key for c in check.contradictions(info)]


def _many_refuses(check, info) -> bool:
    """Whether the many-frame check (its screen, then the one-frame check) refuses the frame."""
    try:
        check.check_many([info])
    except ShipstarError:
        return True
    return False


SENSOR_AND_CAMERA = [
    # (SENSOR, INSTRUME), names = (sensor, camera), the cards that contradict
    (("A1", "A1"), ("A1", "A1"), []),
    (("A1", "A1"), ("A1", "A2"), ["INSTRUME"]),            # the camera's model of another camera
    (("A1", "A1"), ("A2", "A1"), ["SENSOR"]),              # A1's frames calibrated as sensor A2
    (("A1", "A1"), ("A2", "A2"), ["SENSOR", "INSTRUME"]),
    (("A1", ""), ("A1", "A2"), []),                        # no INSTRUME: only SENSOR compared
    (("", "A1"), ("A1", "A2"), ["INSTRUME"]),              # no SENSOR: only INSTRUME compared
    (("", "A1"), ("A2", "A1"), []),
    (("", ""), ("A1", "A2"), []),                          # neither: nothing to compare
    (("bow", "A1"), ("bow", "A1"), []),                    # a sensor named apart from its camera
    (("A1", "A1"), (), []),                                # no names given: not checked
]


@pytest.mark.parametrize("cards, names, expected", SENSOR_AND_CAMERA)
def test_each_card_is_compared_with_what_it_names(cards, names, expected):
    check = HeaderCheck(names=names, given_name="--sensor X (camera Y)")
    info = _info(*cards)
    assert _keys(check, info) == expected
    assert _many_refuses(HeaderCheck(names=names, given_name="--sensor X (camera Y)"), info) == bool(expected)
    if expected:
        with pytest.raises(ShipstarError) as exc:
            check(info)
        assert str(exc.value).startswith(f"frame A1_00000.fits: header {expected[0]} = ")
    else:
        assert check(info) == []


def test_the_camera_card_is_refused_even_where_the_sensor_card_matches():
    """The repro: `calibrate install --frames dock/A1 --sensor A1 --camera A2` (exit 0 before, 0.31 deg off)."""
    check = HeaderCheck(names=("A1", "A2"), given_name="--sensor A1 (camera A2)")
    with pytest.raises(ShipstarError) as exc:
        check(_info("A1", "A1"))
    line = str(exc.value)
    assert line == ("frame A1_00000.fits: header INSTRUME = 'A1' but the camera is 'A2' (--sensor A1 (camera A2); "
                    f"INSTRUME must name the camera); {TRUST_HINT}")
    assert "\n" not in line


def test_the_sensor_card_is_refused_even_where_the_camera_card_matches():
    """The repro: `calibrate install --frames dock/A1 --sensor A2 --camera A1` wrote an A2 file from A1's frames."""
    check = HeaderCheck(names=("A2", "A1"), given_name="--sensor A2 (camera A1)")
    with pytest.raises(ShipstarError, match=r"header SENSOR = 'A1' but the sensor is 'A2' \(--sensor A2 \(camera A1\)"):
        check(_info("A1", "A1"))


@pytest.mark.parametrize("cards, expected", [
    (("A1", "A1"), ["SENSOR"]),            # as before: one line, the SENSOR card's
    (("A2", "A1"), ["INSTRUME"]),          # SENSOR agrees, INSTRUME names another camera
    (("", "A1"), ["INSTRUME"]),
    (("A1", ""), ["SENSOR"]),
    (("A2", "A2"), []),
    (("", ""), []),
])
def test_commands_with_only_a_camera_compare_each_card_present_with_it(cards, expected):
    check = HeaderCheck(names=("A2",), given_name="--camera A2")
    info = _info(*cards)
    assert _keys(check, info) == expected
    assert _many_refuses(HeaderCheck(names=("A2",), given_name="--camera A2"), info) == bool(expected)


def test_trust_flags_records_each_card_and_check_many_agrees_with_one_by_one():
    infos = [_info("A1", "A1", f"f{k}.fits") for k in range(3)] + [_info("", "A1", "f3.fits"),
                                                                     _info("A1", "", "f4.fits")]

    def make(trust):
        return HeaderCheck(names=("A1", "A2"), given_name="--sensor A1=d (camera A2)", trust_flags=trust,
                           sensor="A1")

    one = make(True)
    for info in infos:
        one(info)
    many = make(True)
    many.check_many(infos)
    assert one.overrides() == many.overrides()
    (o,) = many.overrides()
    assert (o["sensor"], o["key"], o["n_frames"]) == ("A1", "INSTRUME", 4)
    assert o["first"].startswith("frame f0.fits: header INSTRUME = 'A1' but the camera is 'A2'")
    with pytest.raises(ShipstarError, match="frame f0.fits: header INSTRUME"):
        make(False).check_many(infos)


def test_names_are_sensor_then_camera():
    with pytest.raises(ValueError):
        HeaderCheck(names=("A1", "A1", "A2"))


@pytest.mark.parametrize("names", [("A1", "A1"), ("A1",), ("bow", "bow-cam")])
def test_an_instrume_card_with_a_camera_make_is_not_a_contradiction(names):
    """FITS's INSTRUME is often the capture software's make and model: only another camera
    shipstar knows (a preset, a camera of the run's other sensors) contradicts."""
    sensor = names[0] if len(names) == 2 else ""
    for instrume in ("ZWO ASI1600MM Pro", "QHY600M", "a1"):
        info = _info(sensor, instrume)
        assert _keys(HeaderCheck(names=names, given_name="x"), info) == []
        assert not _many_refuses(HeaderCheck(names=names, given_name="x"), info)


def test_the_run_s_other_cameras_are_known_besides_the_presets():
    check = HeaderCheck(names=("bow", "bow-cam"), given_name="--sensor bow (camera bow-cam)",
                        known_cameras=["bow-cam", "stern-cam"])
    assert _keys(check, _info("bow", "stern-cam")) == ["INSTRUME"]      # the stern's camera's frames
    assert _keys(check, _info("bow", "seed004")) == ["INSTRUME"]        # a preset
    assert _keys(check, _info("bow", "bow-cam")) == []
    assert _keys(HeaderCheck(names=("bow", "bow-cam"), given_name="x"), _info("bow", "stern-cam")) == []
