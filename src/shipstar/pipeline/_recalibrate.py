"""A sensor's installation re-estimated at sea relative to the reference sensor (issue 14
item 3, third bullet; ``shipstar calibrate install --at-sea``).

``measure``'s mount estimator (:mod:`shipstar.pipeline._mounts`) gives, for each
non-reference sensor B, the static rotation ``s`` of B's mount relative to the reference
mount beyond what the installation files give (deck axes bow / up / starboard, at the
session's mean roll and pitch; the wave-period flexure and the clock offset are estimated
with it and do not enter it).  B's installation is then

    C_deck_from_sensor_new = Exp([s] x) C_deck_from_sensor_file

(the mount turned actively, as the simulator's flexure), so that the joint solution with
the new file needs no static correction.  Its uncertainty (docs/uncertainty.md's
``total``): the estimate's sigma of ``s`` and the reference sensor's own installation
uncertainty (its ``total_*``, else ``sem_*``: B is re-tied to the reference mount, so the
reference's calibration error is carried over), each propagated to B's (az, el, roll)
through the Jacobian of the angles against a deck rotation.  Without flexure and with a
clock offset the same holds (the 10-parameter model separates them).
"""

from __future__ import annotations

import math

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.units import ASEC2RAD, RAD2ASEC

__all__ = ["at_sea_installation", "angles_per_deck_rotation"]

_AXES = ("bow", "up", "starboard")
_ANGLES = ("az", "el", "roll")


def angles_per_deck_rotation(installation) -> np.ndarray:
    """(3, 3) d(az, el, roll) / d(phi) (rad / rad) at the installation: how a small active
    rotation ``Exp([phi] x)`` of the mount (deck axes) changes its installation angles."""
    from shipstar.frames import C_deck_from_sensor as _C_deck_from_sensor
    from shipstar.pipeline._motion import rotvecs

    a0 = np.array([installation.az_rad, installation.el_rad, installation.roll_rad])
    C0 = _C_deck_from_sensor(*a0)
    J = np.zeros((3, 3))               # d(phi) / d(angles)
    eps = 1e-7
    for i in range(3):
        da = np.zeros(3)
        da[i] = eps
        Cp, Cm = _C_deck_from_sensor(*(a0 + da)), _C_deck_from_sensor(*(a0 - da))
        J[:, i] = (rotvecs(Cp @ C0.T)[0] - rotvecs(Cm @ C0.T)[0]) / (2.0 * eps)
    return np.linalg.inv(J)


def _finite3(values) -> np.ndarray:
    v = np.array([float(x) for x in values], float) if values is not None else np.full(3, np.nan)
    return np.where(np.isfinite(v), v, 0.0)


def at_sea_installation(result, configs, sensor: str, *, previous_installation: str = "",
                        session: str = ""):
    """The installation of ``sensor`` re-estimated from a processed at-sea session.

    Parameters
    ----------
    result : SessionResult
        ``process_session`` of at least the reference sensor and ``sensor``.
    configs : sequence of SensorConfig
        The configs the session was processed with (their installation files).
    sensor : str
        The sensor to recalibrate (not the reference).
    previous_installation : str
        The file its installation came from (recorded).
    session : str
        Session label recorded in the file.

    Returns
    -------
    (Installation, dict)
        The new installation (``at_sea`` provenance set) and a JSON-able report.
    """
    from shipstar.calibrate._installation_model import Installation
    from shipstar.pipeline._motion import expm_rotvec
    from shipstar.pipeline._stats import session_summary

    by_name = {c.name: c for c in configs}
    ref = result.reference_sensor
    if sensor not in by_name:
        raise ShipstarError(f"sensor {sensor!r} is not among the session's sensors ({', '.join(by_name)})")
    if sensor == ref:
        raise ShipstarError(f"sensor {sensor!r} is the reference sensor: recalibrate another one against it, or "
                            f"give another --reference")
    summary = session_summary(result)
    flex = (summary.get("flexure") or {}).get(sensor) or {}
    n = int(flex.get("n_epochs", 0) or 0)
    rot = np.array([(flex.get("static_arcsec") or {}).get(a) for a in _AXES], dtype=float)
    sig = np.array([(flex.get("static_sigma_arcsec") or {}).get(a) for a in _AXES], dtype=float)
    if n == 0 or not (np.all(np.isfinite(rot)) and np.all(np.isfinite(sig))):
        b = summary["sensors"]
        raise ShipstarError(f"no estimate of {sensor}'s mount relative to {ref}: {n} epochs where both solved "
                            f"(needs at least 12; {sensor} solved {b[sensor]['n_solved']} of {b[sensor]['n_frames']} "
                            f"frames, {ref} {b[ref]['n_solved']} of {b[ref]['n_frames']})")
    old = by_name[sensor].installation
    ref_inst = by_name[ref].installation
    C_new = expm_rotvec(rot * ASEC2RAD) @ old.C_deck_from_sensor
    # uncertainty: the estimate's and the reference's, both as deck rotations -> B's angles
    new_probe = Installation.from_matrix(sensor, old.camera, C_new)
    D_new = angles_per_deck_rotation(new_probe)
    est_ang = np.sqrt(np.diag(D_new @ np.diag(sig ** 2) @ D_new.T))                 # arcsec (linear)
    ref_tot = _finite3(getattr(ref_inst, "total_arcsec", None))
    if not np.any(ref_tot > 0):
        ref_tot = _finite3(getattr(ref_inst, "sem_arcsec", None))
    J_ref = np.linalg.inv(angles_per_deck_rotation(ref_inst))                         # d(phi) / d(angles)
    cov_ref_deck = J_ref @ np.diag(ref_tot ** 2) @ J_ref.T
    ref_ang = np.sqrt(np.maximum(0.0, np.diag(D_new @ cov_ref_deck @ D_new.T)))
    total = np.sqrt(est_ang ** 2 + ref_ang ** 2)
    off = (summary.get("time_offsets_s") or {}).get(sensor) or {}
    start, end = _span(result)
    at_sea = {"reference_sensor": ref, "start_utc": start, "end_utc": end, "n_epochs": n,
              **{f"rot_{a}_arcsec": float(r) for a, r in zip(_AXES, rot)},
              **{f"sigma_{a}_arcsec": float(s) for a, s in zip(_AXES, sig)},
              "clock_offset_s": float(off["offset_s"]) if off.get("offset_s") is not None else math.nan,
              "clock_sigma_s": float(off["sigma_s"]) if off.get("sigma_s") is not None else math.nan,
              "previous_installation": str(previous_installation)}
    warnings = []
    amp = flex.get("wave_amplitude_arcsec") or {}
    amp_sig = flex.get("wave_amplitude_sigma_arcsec") or {}
    big = [f"{a} {amp[a]:.1f}''" for a in _AXES if amp.get(a) is not None and amp_sig.get(a) is not None
           and amp[a] > max(3.0 * amp_sig[a], 1.0)]
    if big:
        warnings.append(f"the mount flexes at the wave period ({', '.join(big)} amplitude): this file holds the "
                        f"static part at the session's mean roll and pitch; measure estimates the rest")
    if off.get("applied"):
        warnings.append(f"{sensor}'s clock is {off['offset_s'] * 1e3:.3f} ms off its headers (estimated with the "
                        f"rotation, not in it)")
    frames = summary["sensors"][sensor]
    budget = ({"source": f"at-sea estimate of the mount's rotation relative to {ref} ({n} epochs)",
               "sigma": "1 sigma", **{f"{a}_arcsec": float(x) for a, x in zip(_ANGLES, est_ang)}},
              {"source": f"reference sensor {ref}'s installation (its total, carried over)", "sigma": "1 sigma",
               **{f"{a}_arcsec": float(x) for a, x in zip(_ANGLES, ref_ang)}})
    inst = Installation.from_matrix(
        sensor, old.camera, C_new, sem_arcsec=tuple(float(x) for x in est_ang),
        total_arcsec=tuple(float(x) for x in total), uncertainty=budget,
        n_frames=int(frames["n_frames"]), n_used=n, n_failed=int(frames["n_frames"] - frames["n_solved"]),
        session=session, date_utc=start, warnings=tuple(warnings), at_sea=at_sea)
    d_ang = (np.array([inst.az_rad, inst.el_rad, inst.roll_rad])
             - np.array([old.az_rad, old.el_rad, old.roll_rad])) * RAD2ASEC
    report = {"sensor": sensor, "reference_sensor": ref, "camera": old.camera,
              "az_deg": math.degrees(inst.az_rad), "el_deg": math.degrees(inst.el_rad),
              "roll_deg": math.degrees(inst.roll_rad),
              "change_arcsec": dict(zip(_ANGLES, (float(x) for x in d_ang))),
              "sem_arcsec": dict(zip(_ANGLES, (float(x) for x in est_ang))),
              "total_arcsec": dict(zip(_ANGLES, (float(x) for x in total))),
              "rotation_arcsec": dict(zip(_AXES, (float(x) for x in rot))),
              "rotation_sigma_arcsec": dict(zip(_AXES, (float(x) for x in sig))),
              "n_epochs": n, "start_utc": start, "end_utc": end,
              "time_offset_s": {k: off.get(k) for k in ("offset_s", "sigma_s", "applied")},
              "wave_amplitude_arcsec": amp, "warnings": warnings,
              "previous_installation": str(previous_installation)}
    return inst, report


def _span(result) -> tuple:
    from shipstar.sky.time import iso_from_utc_jd

    ep = [e for e in result.epochs if getattr(e, "mounts", None) is not None] or list(result.epochs)
    if not ep:
        return "", ""
    return (iso_from_utc_jd(ep[0].utc_jd1, ep[0].utc_jd2, 6), iso_from_utc_jd(ep[-1].utc_jd1, ep[-1].utc_jd2, 6))
