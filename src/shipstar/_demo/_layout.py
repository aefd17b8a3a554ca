"""The error model (``shipstar.errormodel``) of the installed layout, beside the measured errors.

For each sensor: its attitude accuracy from the session's own numbers (median stars used
and median per-star noise, :func:`shipstar.errormodel.sensor_accuracy`), its installation
and the dock calibration's standard error of the mean as the installation error;
:func:`shipstar.errormodel.ship_covariance` gives the ship attitude covariance as the
ship rolls (pitch 0).  Fused: seed 003's rule (heading averaged, pitch from the fore-aft
sensor, roll from the athwartship one) and the information-weighted joint solution.
The measured RMS of each method is binned by the true ship roll at each epoch, over the
centroid-level epochs (whose star noise is the one the model is given; the image-level
frames at sea are smeared).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shipstar.units import DEG2RAD, RAD2ASEC

__all__ = ["LayoutSweep", "layout_sweep"]

#: Measured errors are binned by true ship roll in bins this wide (deg).
ROLL_BIN_DEG = 1.0


@dataclass(frozen=True, eq=False)
class LayoutSweep:
    """Predicted 1-sigma (heading, pitch, roll) against ship roll, and the measured RMS.

    Attributes
    ----------
    roll_deg : (n,)
    predicted : tuple of (label, (n, 3) arcsec)
    measured : tuple of (label, roll bin centres (m,), RMS (m, 3) arcsec)
    accuracy : dict of sensor name -> SensorAccuracy
    install_errors_arcsec : dict of sensor name -> (3,)
    session_rms_arcsec : dict of label -> {"predicted": (3,), "measured": (3,)}
        Over the centroid-level epochs: the model's RMS at each epoch's true roll, and
        the measured RMS error.
    """

    roll_deg: np.ndarray
    predicted: tuple
    measured: tuple
    accuracy: dict
    install_errors_arcsec: dict
    session_rms_arcsec: dict


def _sigma(P: np.ndarray) -> np.ndarray:
    return np.sqrt(np.diagonal(P, axis1=-2, axis2=-1)) * RAD2ASEC


def _binned(method, truth_t_s, truth_roll_deg, lim_deg: float):
    """(bin centres, RMS (m, 3)) of a method's errors binned by the true roll."""
    from shipstar.pipeline import rms_arcsec

    roll = np.interp(method.t_s, truth_t_s, truth_roll_deg)
    edges = np.arange(-lim_deg, lim_deg + ROLL_BIN_DEG, ROLL_BIN_DEG)
    centres, rms = [], []
    usable = np.all(np.isfinite(method.errors_arcsec), axis=1) & ~method.image_level
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (roll >= lo) & (roll < hi) & usable
        if sel.sum() >= 3:
            centres.append(0.5 * (lo + hi))
            rms.append(rms_arcsec(method.errors_arcsec[sel]))
    return np.array(centres), np.array(rms).reshape(-1, 3)


def layout_sweep(spec, dock, sea, *, roll_limit_deg: float = 10.0) -> LayoutSweep:
    """The error model of the installed sensors against ship roll (see the module docstring).

    Parameters
    ----------
    spec : SessionSpec
        The sea session (sensors, cameras).
    dock : tuple of DockSensor
    sea : SeaOutcome
    roll_limit_deg : float
        The sweep covers +- this.
    """
    from shipstar.errormodel import sensor_accuracy, ship_covariance

    roll = np.linspace(-roll_limit_deg, roll_limit_deg, 81)
    by_name = {d.name: d for d in dock}
    stats = {s.name: s for s in sea.sensors}
    P, acc, inst_err = {}, {}, {}
    for s in spec.sensors:
        (n_stars, sigma_star), inst = stats[s.name].model_inputs(), by_name[s.name].installation
        acc[s.name] = sensor_accuracy(s.camera.fov_deg, max(n_stars, 2.0), sigma_star,
                                      fov_height_deg=s.camera.fov_height_deg)
        inst_err[s.name] = np.asarray(inst.sem_arcsec, float)
        P[s.name] = ship_covariance(acc[s.name], inst.az_rad, inst.el_rad, roll_rad=inst.roll_rad,
                                    install_errors_arcsec=inst_err[s.name], ship_roll_rad=roll * DEG2RAD)
    predicted = [(f"single {n}", _sigma(p)) for n, p in P.items()]
    if len(P) > 1:
        joint = np.linalg.inv(sum(np.linalg.inv(p) for p in P.values()))
        fore, athw = sea.fore_aft_sensor, sea.athwartship_sensor
        if fore and athw:
            seed = np.stack([np.sqrt(sum(p[:, 0, 0] for p in P.values())) / len(P),
                             np.sqrt(P[fore][:, 1, 1]), np.sqrt(P[athw][:, 2, 2])], axis=-1) * RAD2ASEC
            predicted.append(("seed rule", seed))
        predicted.append(("joint", _sigma(joint)))
    lim = float(np.nanmax(np.abs(sea.truth_deg[:, 2]))) + ROLL_BIN_DEG
    measured = [(m.name, *_binned(m, sea.truth_t_s, sea.truth_deg[:, 2], lim)) for m in sea.methods]
    return LayoutSweep(roll, tuple(predicted), tuple(measured), acc, inst_err,
                       _session_rms(roll, dict(predicted), sea))


def _session_rms(roll_grid, predicted: dict, sea) -> dict:
    """Model and measured RMS of each method over the centroid-level epochs."""
    out = {}
    for m in sea.methods:
        if m.name not in predicted or m.image_level.all():
            continue
        sel = ~m.image_level & np.all(np.isfinite(m.errors_arcsec), axis=1)
        roll = np.interp(m.t_s[sel], sea.truth_t_s, sea.truth_deg[:, 2])
        sig = np.stack([np.interp(roll, roll_grid, predicted[m.name][:, k]) for k in range(3)], axis=-1)
        out[m.name] = {"predicted": np.sqrt(np.mean(sig ** 2, axis=0)), "measured": m.rms_arcsec("centroid")}
    return out
