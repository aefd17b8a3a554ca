"""``shipstar calibrate install --at-sea`` (issue 14 item 3): a drifted sensor recalibrated
against the reference sensor from at-sea frames (pipeline/_recalibrate.py).

A 4 s image-level sea session (rendered FITS) whose A2 installation file is off by a
rotation of 29'' (20 / -15 / 15'' about bow / up / starboard) from the installation the
frames were rendered with."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from shipstar.calibrate.installation import Installation, load_installation, save_installation
from shipstar.cli import main
from shipstar.errors import ShipstarError
from shipstar.pipeline._motion import expm_rotvec
from shipstar.units import ASEC2RAD, RAD2ASEC

ERR_ARCSEC = np.array([20.0, -15.0, 15.0])


def _angles(inst) -> np.ndarray:
    return np.array([inst.az_rad, inst.el_rad, inst.roll_rad]) * RAD2ASEC


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    from shipstar.simulate._session import sea_session, write_session

    root = tmp_path_factory.mktemp("atsea")
    spec = sea_session(duration_s=4.0)
    write_session(spec, root / "sea")
    true = {}
    for s in spec.sensors:
        true[s.name] = Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor)
        C = s.C_deck_from_sensor if s.name == "A1" else expm_rotvec(-ERR_ARCSEC * ASEC2RAD) @ s.C_deck_from_sensor
        save_installation(Installation.from_matrix(s.name, s.camera.name, C), root / f"{s.name}.toml")
    return root, true


def _args(root, *extra):
    return ["calibrate", "install", "--at-sea", "--sensor", "A2", "--frames", f"A1={root / 'sea/A1'}",
            "--frames", f"A2={root / 'sea/A2'}", "--install", str(root / "A1.toml"), str(root / "A2.toml"),
            "--track", str(root / "sea/track.csv"), "--weather", str(root / "sea/weather.csv"), *extra]


def test_at_sea_recovers_the_true_installation_within_its_uncertainty(session, capsys):
    root, true = session
    out = root / "A2.atsea.toml"
    assert main(_args(root, "--out", str(out), "--json")) == 0
    rep = json.loads(capsys.readouterr().out)
    new, old = load_installation(out), load_installation(root / "A2.toml")
    before = _angles(old) - _angles(true["A2"])
    after = _angles(new) - _angles(true["A2"])
    assert np.linalg.norm(before) > 25.0
    total = np.array(new.total_arcsec)
    assert np.all(np.isfinite(total)) and np.all(total > 0) and np.all(total < 5.0)
    assert np.all(np.abs(after) <= 3.0 * total), (after, total)
    # the rotation found is the one put into the file, within its sigmas
    rot = np.array([rep["rotation_arcsec"][a] for a in ("bow", "up", "starboard")])
    sig = np.array([rep["rotation_sigma_arcsec"][a] for a in ("bow", "up", "starboard")])
    assert np.all(np.abs(rot - ERR_ARCSEC) <= 3.0 * sig + 0.5)
    # provenance
    p = new.at_sea
    assert p["reference_sensor"] == "A1" and p["n_epochs"] >= 30 and rep["n_epochs"] == p["n_epochs"]
    assert p["start_utc"].startswith("2013-03-15T12:16:00") and p["end_utc"] > p["start_utc"]
    assert p["previous_installation"].endswith("A2.toml")
    assert "at_sea = true" in out.read_text() and new.sensor == "A2" and new.camera == old.camera
    assert [r["source"].split()[0] for r in new.uncertainty] == ["at-sea", "reference"]
    # measure takes the new file
    assert load_installation(out).C_deck_from_sensor.shape == (3, 3)


def test_at_sea_refuses_bad_sensor_choices(session, capsys):
    root, _ = session
    out = root / "x.toml"
    assert main(_args(root, "--out", str(out), "--reference", "A2")) == 2
    assert "--reference and --sensor are both A2" in capsys.readouterr().err
    args = _args(root, "--out", str(out))
    args[args.index("--sensor") + 1] = "A3"
    assert main(args) == 2
    assert "--sensor A3 has no --frames" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["calibrate", "install", "--at-sea", "--sensor", "A2", "--out", str(out)])
    assert exc.value.code == 2
    assert "required" in capsys.readouterr().err
    assert not out.exists()


def test_at_sea_provenance_round_trip_and_refusals(tmp_path):
    prov = {"reference_sensor": "A1", "start_utc": "a", "end_utc": "b", "n_epochs": 40, "rot_bow_arcsec": 1.5,
            "sigma_bow_arcsec": 0.2, "clock_offset_s": math.nan, "previous_installation": "A2.toml"}
    inst = Installation.from_matrix("A2", "A2", np.eye(3), at_sea=prov)
    save_installation(inst, tmp_path / "a.toml")
    back = load_installation(tmp_path / "a.toml").at_sea
    assert back["n_epochs"] == 40 and back["rot_bow_arcsec"] == 1.5 and math.isnan(back["clock_offset_s"])
    assert load_installation(tmp_path / "a.toml").dock is None
    text = (tmp_path / "a.toml").read_text()
    for bad, msg in ((text.replace("n_epochs = 40", "n_epochs = \"x\""), "n_epochs must be int"),
                     (text.replace("n_epochs = 40", "bogus = 1"), "bogus"),
                     (text.replace("at_sea = true", "at_sea = false"), "needs at_sea = true")):
        (tmp_path / "b.toml").write_text(bad)
        with pytest.raises(ShipstarError, match=msg):
            load_installation(tmp_path / "b.toml")
    # a dock file has no provenance
    save_installation(Installation.from_matrix("A2", "A2", np.eye(3)), tmp_path / "c.toml")
    assert load_installation(tmp_path / "c.toml").at_sea is None
    assert "at_sea" not in (tmp_path / "c.toml").read_text()
