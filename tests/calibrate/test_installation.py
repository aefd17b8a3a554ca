"""Installation calibration in dock (seed 000 section 3): matrices, SO(3) mean, files, the seed's session."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shipstar import frames as F
from shipstar.calibrate.installation import (
    DockConditions,
    Installation,
    calibrate_installation,
    installation_from_frame,
    load_installation,
    mean_rotation,
    robust_mean_rotation,
    save_installation,
)
from shipstar.errors import ShipstarError
from shipstar.units import ASEC2RAD, DEG2RAD, RAD2ASEC

HEADING = (46.0 + 28.0 / 60.0 + 28.51 / 3600.0) * DEG2RAD      # seed 000
A1 = (185.1093 * DEG2RAD, 39.3734 * DEG2RAD, -0.2262 * DEG2RAD)   # seed 000 Tab. 2
A1_SEED_STD_ARCSEC = (9.1835, 5.8931, 63.552)                     # seed 000 Tab. 2


def _exp(phi):
    """Rotation matrix exp([phi x]) (Rodrigues), independent of shipstar."""
    phi = np.asarray(phi, float)
    a = np.linalg.norm(phi)
    if a == 0:
        return np.eye(3)
    k = phi / a
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def _quaternion_average(C):
    """Markley et al. (2007): the eigenvector of sum(q q^T) with the largest eigenvalue."""
    q = F.q_wxyz_from_matrix(C)
    M = np.einsum("ni,nj->ij", q, q)
    return F.matrix_from_q_wxyz(np.linalg.eigh(M)[1][:, -1])


def test_installation_from_frame_inverts_the_chain():
    C_hd = F.C_hor_from_deck(HEADING, 0.3 * DEG2RAD, -0.2 * DEG2RAD)
    C_ds = F.C_deck_from_sensor(*A1)
    np.testing.assert_allclose(installation_from_frame(C_hd @ C_ds, C_hd), C_ds, atol=1e-15)
    stack = np.stack([C_hd @ C_ds] * 4)
    assert installation_from_frame(stack, C_hd).shape == (4, 3, 3)
    with pytest.raises(ShipstarError):
        installation_from_frame(np.eye(2), C_hd)


def test_physical_check_a1_looks_aft_and_up():
    """docs/conventions.md: A1 at 185 deg / 40 deg on a level ship heading 46.4746 deg looks
    at azimuth 231.4746 deg, elevation 40 deg; the calibration gives the angles back."""
    C_hd = F.C_hor_from_deck(46.4746 * DEG2RAD, 0.0, 0.0)
    C_hs = C_hd @ F.C_deck_from_sensor(185 * DEG2RAD, 40 * DEG2RAD, 0.0)
    az, el = F.az_el_from_unit(C_hs[:, 0])
    assert az * 180 / math.pi == pytest.approx(231.4746, abs=1e-9)
    assert el * 180 / math.pi == pytest.approx(40.0, abs=1e-9)
    inst = calibrate_installation(np.stack([C_hs, C_hs]), C_hd, sensor="A1", camera="A1")
    assert inst.az_rad == pytest.approx(185 * DEG2RAD, abs=1e-12)
    assert inst.el_rad == pytest.approx(40 * DEG2RAD, abs=1e-12)


def test_mean_rotation_of_symmetric_perturbations_is_the_centre():
    C0 = F.C_deck_from_sensor(*A1)
    rng = np.random.default_rng(2)
    phis = rng.normal(0, 60 * ASEC2RAD, (50, 3))
    C = np.array([C0 @ _exp(p) for p in phis] + [C0 @ _exp(-p) for p in phis])
    assert F.rotation_angle_rad(mean_rotation(C).T @ C0) * RAD2ASEC < 1e-6


def test_mean_rotation_agrees_with_quaternion_averaging():
    C0 = F.C_deck_from_sensor(*A1)
    rng = np.random.default_rng(4)
    C = np.array([C0 @ _exp(rng.normal(0, [60, 10, 10]) * ASEC2RAD) for _ in range(200)])
    m = mean_rotation(C)
    assert F.rotation_angle_rad(m.T @ _quaternion_average(C)) * RAD2ASEC < 1e-6
    w = rng.uniform(0.5, 2.0, len(C))
    assert np.allclose(m @ m.T, np.eye(3), atol=1e-14)
    assert F.rotation_angle_rad(mean_rotation(C, w).T @ m) * RAD2ASEC < 5.0
    with pytest.raises(ShipstarError):
        mean_rotation(C, -w)
    with pytest.raises(ShipstarError):
        mean_rotation(np.full((2, 3, 3), np.nan))


def test_robust_mean_rejects_an_outlying_frame():
    C0 = F.C_deck_from_sensor(*A1)
    rng = np.random.default_rng(6)
    C = np.array([C0 @ _exp(rng.normal(0, 5, 3) * ASEC2RAD) for _ in range(40)])
    C[7] = C0 @ _exp([0.0, 0.02, 0.0])            # 69 arcmin off
    mean, keep = robust_mean_rotation(C)
    assert not keep[7] and keep.sum() == 39
    assert F.rotation_angle_rad(mean.T @ C0) * RAD2ASEC < 3.0
    naive = mean_rotation(C)
    assert F.rotation_angle_rad(naive.T @ C0) * RAD2ASEC > 50.0


def test_small_sessions_do_not_reject_good_frames():
    """A MAD from a few frames is a noisy scale: 5 x 1.4826 MAD rejected a good frame in
    25 % of 4-frame and 4 % of 20-frame Gaussian sessions.  The threshold widened for the
    number of frames rejects none in 300 sessions of each size (expected: 5.7e-7 per
    angle and frame), and still rejects a misidentified frame among 40."""
    rng = np.random.default_rng(12)
    C0 = F.C_deck_from_sensor(*A1)
    for n in (4, 6, 20):
        for _ in range(300):
            C = np.array([C0 @ _exp(rng.normal(0, [60, 10, 10]) * ASEC2RAD) for _ in range(n)])
            assert robust_mean_rotation(C)[1].all()


def test_mad_threshold_is_the_student_t_quantile_at_the_gaussian_tail():
    """Against scipy.stats (the module shipstar no longer imports for it): Student-t with
    0.3675 (n - 1) dof (the MAD's efficiency) at the tail of k Gaussian sigmas; the docstring's figures."""
    from scipy import stats

    from shipstar.calibrate._installation_mean import mad_threshold_k

    for k in (3.0, 5.0):
        for n in (2, 4, 20, 40, 160, 1000):
            ref = stats.t.isf(stats.norm.sf(k), 0.3675 * (n - 1))
            assert mad_threshold_k(k, n) == pytest.approx(ref, rel=1e-12)
    assert [round(mad_threshold_k(5.0, n), 1) for n in (160, 40, 20)] == [5.6, 8.5, 17.2]


def test_calibration_reproduces_injected_scatter():
    """Frames scattered like seed 000 Tab. 2 (9.18'', 5.89'', 63.55''): std and mean come back."""
    rng = np.random.default_rng(8)
    n = 400
    C_hd = F.C_hor_from_deck(HEADING, 0.0, 0.0)
    angles = np.array(A1) + rng.normal(0, 1, (n, 3)) * np.array(A1_SEED_STD_ARCSEC) * ASEC2RAD
    C_hs = C_hd @ F.C_deck_from_sensor(angles[:, 0], angles[:, 1], angles[:, 2])
    inst = calibrate_installation(C_hs, C_hd, sensor="A1", camera="A1", session="synthetic")
    assert inst.n_frames == n and inst.n_used >= n - 2 and inst.n_failed == 0
    np.testing.assert_allclose(inst.std_arcsec, A1_SEED_STD_ARCSEC, rtol=0.1)
    bias = (np.array([inst.az_rad, inst.el_rad, inst.roll_rad]) - A1) * RAD2ASEC
    assert np.all(np.abs(bias) < 4 * np.array(inst.sem_arcsec))


def test_reported_sem_is_the_scatter_of_session_means():
    """Monte Carlo over 400 independent sessions of 25 frames (seed 000 Tab. 2 scatter):
    the scatter of the sessions' mean angles is what each session reports as its standard
    error, within the sampling error of a standard deviation from 400 samples (3.5 %)."""
    rng = np.random.default_rng(10)
    C_hd = F.C_hor_from_deck(HEADING, 0.0, 0.0)
    sessions, n = 400, 25
    means, sems = [], []
    for _ in range(sessions):
        angles = np.array(A1) + rng.normal(0, 1, (n, 3)) * np.array(A1_SEED_STD_ARCSEC) * ASEC2RAD
        inst = calibrate_installation(C_hd @ F.C_deck_from_sensor(*angles.T), C_hd, sensor="A1", camera="A1")
        means.append([inst.az_rad, inst.el_rad, inst.roll_rad])
        sems.append(inst.sem_arcsec)
    scatter = np.std(np.array(means) * RAD2ASEC, axis=0, ddof=1)
    reported = np.sqrt(np.mean(np.square(sems), axis=0))
    np.testing.assert_allclose(scatter / reported, 1.0, atol=0.12)          # 3.4 sampling sigmas
    np.testing.assert_allclose(reported, np.array(A1_SEED_STD_ARCSEC) / math.sqrt(n), rtol=0.05)


def test_failed_frames_are_counted_and_too_few_refused():
    C_hd = F.C_hor_from_deck(HEADING, 0.0, 0.0)
    C_hs = np.stack([C_hd @ F.C_deck_from_sensor(*A1)] * 5)
    C_hs[1] = np.nan
    inst = calibrate_installation(C_hs, C_hd, solved=[True, False, True, False, True], sensor="A1", camera="A1")
    assert (inst.n_frames, inst.n_used, inst.n_failed) == (5, 3, 2)
    with pytest.raises(ShipstarError, match=r"1 of 3 frames solved.*not identified"):
        calibrate_installation(C_hs[:3], C_hd, solved=[True, False, False], sensor="A1", camera="A1",
                               reasons=["", "not identified", "not identified"])


def test_toml_round_trip(tmp_path):
    dock = DockConditions(HEADING, 0.0, 0.0, 31.9 * DEG2RAD, 120.3 * DEG2RAD, 0.0, 1021.7, 11.1, "erfa", "per-star",
                          xi_rad=4.25 * ASEC2RAD, eta_rad=-7.5 * ASEC2RAD, eop_quality="extrapolated",
                          dut1_error_s=0.0123, polar_motion_error_arcsec=0.04, relative_humidity=0.4,
                          humidity_source="given", wavelength_um=0.6, eop_source="/data/finals2000A.all")
    budget = ({"source": "wavelength", "sigma": "0.05 um", "az_arcsec": 0.0, "el_arcsec": 0.22, "roll_arcsec": 0.0},)
    inst = Installation(sensor="A1", camera="A1", az_rad=A1[0], el_rad=A1[1], roll_rad=A1[2],
                        std_arcsec=(9.1835, 5.8931, 63.552), sem_arcsec=(0.7, 0.5, 5.0), n_frames=160, n_used=158,
                        n_failed=1, n_rejected=1, session="dock-2013-03-15", date_utc="2013-03-15T12:16:00.000Z",
                        dock=dock, warnings=('Earth orientation "extrapolated"\n 30 days',),
                        total_arcsec=(2.1, 1.1, 5.2), uncertainty=budget)
    path = tmp_path / "A1.install.toml"
    save_installation(inst, path)
    text = path.read_text()
    for key in ("az_deg = 185.1093", "el_deg = 39.3734", "std_roll_arcsec = 63.552", "[dock]", 'camera = "A1"',
                "xi_arcsec = 4.25", "eta_arcsec = -7.5", 'eop_quality = "extrapolated"', "dut1_error_s = 0.0123",
                'warnings = ["Earth orientation \\"extrapolated\\" 30 days"]'):
        assert key in text
    back = load_installation(path)
    assert back == inst
    np.testing.assert_allclose(back.C_deck_from_sensor, F.C_deck_from_sensor(*A1), atol=1e-15)
    assert not list(tmp_path.glob(".*tmp"))


@pytest.mark.parametrize("body, message", [
    ('sensor = "A1"\ncamera = "A1"\naz_deg = 185.0\nel_deg = 39.0\n', "missing roll_deg"),
    ('sensor = "A1"\ncamera = "A1"\naz_deg = "x"\nel_deg = 39.0\nroll_deg = 0.0\n', "az_deg must be a number"),
    ('sensor = "A1"\ncamera = "A1"\naz_deg = nan\nel_deg = 39.0\nroll_deg = 0.0\n', "az_deg must be finite"),
    ('sensor = "A1"\ncamera = "A1"\naz_deg = 1.0\nel_deg = 39.0\nroll_deg = 0.0\nazimuth = 3\n', "unknown key"),
    ('format = "other"\nsensor = "A1"\ncamera = "A1"\naz_deg = 1.0\nel_deg = 2.0\nroll_deg = 0.0\n', "format"),
    ('format_version = 9\nsensor = "A1"\ncamera = "A1"\naz_deg = 1.0\nel_deg = 2.0\nroll_deg = 0.0\n',
     "format_version"),
    ('camera = "A1"\naz_deg = 1.0\nel_deg = 2.0\nroll_deg = 0.0\n', "missing sensor"),
    ('sensor = "A1"\ncamera = "A1"\naz_deg = 1.0\nel_deg = 95.0\nroll_deg = 0.0\n', r"el_deg must be within \[-90, 90\]"),
    ('sensor = "A1"\ncamera = "A1"\naz_deg = 1.0\nel_deg = 2.0\nroll_deg = 0.0\n[dock]\npitch_deg = 1\n',
     "missing dock.heading_deg"),
    ("this is = = not toml", "not valid TOML"),
])
def test_bad_installation_files_name_the_problem(tmp_path, body, message):
    path = tmp_path / "bad.toml"
    path.write_text(body)
    with pytest.raises(ShipstarError, match=message):
        load_installation(path)


def test_missing_installation_file(tmp_path):
    with pytest.raises(ShipstarError, match="no such installation file"):
        load_installation(tmp_path / "nope.toml")


def test_seed_dock_session_recovers_installation_within_one_arcsec():
    """Acceptance: simulated seed-000 dock session (A1 and A2, 0.1 px centroid noise, 16 s at
    10 fps): installation angles recovered with bias < 1''; the per-frame std is reported and,
    for this idealised sensor, far below the seed's measured std (A1 9.18/5.89/63.55'')."""
    from shipstar.pipeline import Frame, SensorConfig, Track, WeatherTable, process_sensor
    from shipstar.simulate._session import dock_session, simulate_centroids

    spec = dock_session()
    frames = simulate_centroids(spec)
    track = Track.fixed(31.9, 120.3)
    weather = WeatherTable.constant(spec.pressure_hpa, spec.temperature_c)
    for s in spec.sensors:
        fr = [Frame.from_centroids(f.utc_jd1, f.utc_jd2, f.xy_px, f.hip, f"#{f.index}") for f in frames[s.name]]
        res = process_sensor(SensorConfig(s.name, s.camera), fr, track, weather)
        assert len(res) == 160 and all(r.solved for r in res)
        inst = calibrate_installation(np.array([r.C_hor_from_sensor for r in res]), spec.motion.C_hor_from_deck(0.0),
                                      sensor=s.name, camera=s.camera.name)
        bias = (np.array([inst.az_rad, inst.el_rad, inst.roll_rad])
                - [s.install_az_rad, s.install_el_rad, s.install_roll_rad]) * RAD2ASEC
        assert np.all(np.abs(bias) < 1.0), (s.name, bias)
        assert np.all(np.isfinite(inst.std_arcsec))
        assert np.all(np.array(inst.std_arcsec) < np.array(A1_SEED_STD_ARCSEC))
        assert inst.std_arcsec[2] > 5 * inst.std_arcsec[1]        # roll about the boresight is weak


def _dock_attitudes(n_frames=20):
    """A1's per-frame sensor attitudes in a simulated seed 000 dock session, processed at
    the dock with and without a deflection of the vertical (xi = 10'', then eta = 10'')."""
    from shipstar.pipeline import Frame, SensorConfig, Track, WeatherTable, process_sensor
    from shipstar.simulate._session import dock_session, simulate_centroids

    spec = dock_session(duration_s=n_frames / 10.0)
    s = spec.sensors[0]
    frames = [Frame.from_centroids(f.utc_jd1, f.utc_jd2, f.xy_px, f.hip, f"#{f.index}")
              for f in simulate_centroids(spec)[s.name]]
    weather = WeatherTable.constant(spec.pressure_hpa, spec.temperature_c)
    out = {}
    for key, track in (("none", Track.fixed(31.9, 120.3)), ("xi", Track.fixed(31.9, 120.3, 0.0, 10.0, 0.0)),
                       ("eta", Track.fixed(31.9, 120.3, 0.0, 0.0, 10.0))):
        res = process_sensor(SensorConfig(s.name, s.camera), frames, track, weather)
        assert all(r.solved for r in res)
        inst = calibrate_installation(np.array([r.C_hor_from_sensor for r in res]), spec.motion.C_hor_from_deck(0.0),
                                      sensor=s.name, camera=s.camera.name)
        out[key] = inst.C_deck_from_sensor
    return out, spec.motion.C_hor_from_deck(0.0)


def _rotation_vector_arcsec(C):
    """Axis * angle of a small rotation (numpy only: the skew part of C)."""
    return np.array([C[2, 1] - C[1, 2], C[0, 2] - C[2, 0], C[1, 0] - C[0, 1]]) / 2.0 * RAD2ASEC


def test_deflection_of_the_vertical_enters_the_installation():
    """Review finding: site.toml's deflection was dropped.  With xi = 10'' the plumb line
    leans north: every direction turns about the east axis, raising the north horizon by
    10''.  The installation found with it differs from the one without by exactly that
    rotation, expressed in the deck frame (C_hd.T R_east(10'') C_hd); eta = 10'' turns the
    sky about the polar axis by eta / cos(lat) = 11.8''."""
    C, C_hd = _dock_attitudes()
    xi = 10.0 * ASEC2RAD
    R_east = np.array([[np.cos(xi), -np.sin(xi), 0.0], [np.sin(xi), np.cos(xi), 0.0], [0.0, 0.0, 1.0]])
    expected = _rotation_vector_arcsec(C_hd.T @ R_east @ C_hd)
    got = _rotation_vector_arcsec(C["xi"] @ C["none"].T)
    assert np.linalg.norm(expected) == pytest.approx(10.0, abs=1e-6)
    np.testing.assert_allclose(got, expected, atol=0.05)          # per-star refraction: < 0.01''
    lat = 31.9 * DEG2RAD
    pole_deck = C_hd.T @ np.array([np.cos(lat), np.sin(lat), 0.0])
    got = _rotation_vector_arcsec(C["eta"] @ C["none"].T)
    assert np.linalg.norm(got) == pytest.approx(10.0 / np.cos(lat), abs=0.05)
    assert abs(got @ pole_deck) == pytest.approx(np.linalg.norm(got), rel=1e-3)


def test_dock_conditions_record_the_deflection(tmp_path):
    dock = DockConditions(HEADING, xi_rad=-12.5 * ASEC2RAD, eta_rad=3.0 * ASEC2RAD)
    inst = Installation.from_matrix("A1", "A1", F.C_deck_from_sensor(*A1), dock=dock)
    save_installation(inst, tmp_path / "a.toml")
    back = load_installation(tmp_path / "a.toml").dock
    assert back.xi_rad * RAD2ASEC == pytest.approx(-12.5) and back.eta_rad * RAD2ASEC == pytest.approx(3.0)
    # files written before the keys existed were processed without a deflection
    old = "\n".join(line for line in (tmp_path / "a.toml").read_text().splitlines()
                    if not line.startswith(("xi_arcsec", "eta_arcsec", "eop_quality", "warnings")))
    (tmp_path / "old.toml").write_text(old)
    back = load_installation(tmp_path / "old.toml")
    assert (back.dock.xi_rad, back.dock.eta_rad, back.dock.eop_quality, back.warnings) == (0.0, 0.0, "", ())
    (tmp_path / "bad.toml").write_text(old + '\neop_quality = "guessed"\n')
    with pytest.raises(ShipstarError, match="eop_quality must be"):
        load_installation(tmp_path / "bad.toml")
