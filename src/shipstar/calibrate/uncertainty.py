"""Uncertainty that includes the model: the systematic budget of a dock calibration and of
ship attitude at sea (docs/uncertainty.md).

The statistical standard error (sem) of a calibration counts only the frame-to-frame
scatter.  The inputs that are the same for every frame (weather sensors, the effective
wavelength of the passband, the refraction model, the dock's heading and level, Earth
orientation) move every frame together and average away nothing.  Each one's effect is
computed here numerically, by finite differences of one documented sigma either way
through the real code (the larger of the two one-sided changes):

- refraction inputs: a grid of 7 x 7 directions over the camera's image at the session's
  mean sensor attitude is un-refracted with the nominal inputs and refracted again with
  one input moved by +-sigma (:func:`shipstar.sky.refraction.refract_hor`, the model the
  session used); the rotation that best maps the nominal onto the perturbed directions
  (least squares, what the attitude solver would find) changes the sensor attitude;
- Earth orientation: the same directions taken to ICRS with the session's Earth
  orientation and back to the horizontal frame with UT1 - UTC or one polar motion
  component moved by its sigma (:func:`shipstar.sky.apparent.frame_context`, ERFA);
- dock heading and level: the known ship attitude moved by its sigma.

The effects are combined in quadrature with the sem (they are independent inputs):
``total = sqrt(sem**2 + sum(effect**2))`` per angle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.frames import (
    C_hor_from_deck,
    installation_angles_from_C_deck_from_sensor,
    ship_angles_from_C_hor_from_deck,
)
from shipstar.units import ASEC2RAD, RAD2ASEC

__all__ = ["InputSigmas", "BudgetRow", "REFRACTION_MODEL_FRACTION", "HUMIDITY_SIGMA_DEFAULTED",
           "refraction_rotation", "eop_rotations", "installation_budget", "ship_budget", "total_arcsec",
           "budget_as_dict"]

#: Relative 1-sigma uncertainty of the refraction *model* (beyond its inputs), as a
#: fraction of the refraction: ``erfa`` is within 0.03'' of ray tracing above 15 deg
#: (docs/refraction.md) and the real atmosphere's temperature structure changes only its
#: small ``tan^3 z`` term; 0.1 % is 0.07'' at 40 deg.  ``almanac``: up to 0.6 % biased
#: against ray tracing (docs/refraction.md), 1 %.  ``none``: the whole refraction.
REFRACTION_MODEL_FRACTION = {"erfa": 0.001, "almanac": 0.01, "none": 1.0}
#: Sigma of the relative humidity when it was not given and 0 was assumed (dry air): a
#: uniform distribution over 0..1 has a 0.29 standard deviation and a mean of 0.5, so the
#: dry default is off by 0.5 on average; 0.5 is used.
HUMIDITY_SIGMA_DEFAULTED = 0.5


@dataclass(frozen=True)
class InputSigmas:
    """Documented 1-sigma uncertainties of the inputs (docs/uncertainty.md).

    Attributes
    ----------
    pressure_hpa : float
        Barometer at the sensor (class-A marine barometer 0.3 hPa, plus height and
        reduction errors): 0.5 hPa.
    temperature_c : float
        Air temperature along the line of sight near the sensor, not at the thermometer
        (ship's structure and dock surfaces warm the air): 1 C.
    relative_humidity : float
        Hygrometer, 0.05 (5 % RH); :data:`HUMIDITY_SIGMA_DEFAULTED` when not measured.
    wavelength_um : float
        Effective wavelength of the passband (the camera's ``wavelength_sigma_um``).
    heading_arcsec, level_arcsec : float
        Dock theodolite heading (2'') and precision levels, each of pitch and roll (1'').
    """

    pressure_hpa: float = 0.5
    temperature_c: float = 1.0
    relative_humidity: float = 0.05
    wavelength_um: float = 0.05
    heading_arcsec: float = 2.0
    level_arcsec: float = 1.0

    def __post_init__(self):
        for name in ("pressure_hpa", "temperature_c", "relative_humidity", "wavelength_um", "heading_arcsec",
                     "level_arcsec"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ShipstarError(f"uncertainty of {name} must be a finite number >= 0, got {v!r}")
            object.__setattr__(self, name, float(v))


@dataclass(frozen=True)
class BudgetRow:
    """One input's effect: its sigma (text with unit) and the effect on three angles (arcsec)."""

    source: str
    sigma: str
    effect_arcsec: tuple

    def as_dict(self, names=("az", "el", "roll")) -> dict:
        return {"source": self.source, "sigma": self.sigma,
                **{f"{n}_arcsec": float(v) for n, v in zip(names, self.effect_arcsec)}}


def total_arcsec(sem_arcsec, rows) -> tuple:
    """``sqrt(sem**2 + sum(effect**2))`` per angle (NaN sem counts as 0)."""
    sem = np.nan_to_num(np.asarray(sem_arcsec, float), nan=0.0)
    eff = np.array([r.effect_arcsec for r in rows], float).reshape(-1, len(sem))
    return tuple(float(x) for x in np.sqrt(sem ** 2 + np.sum(np.nan_to_num(eff) ** 2, axis=0)))


def budget_as_dict(sem_arcsec, rows, names=("az", "el", "roll")) -> dict:
    """JSON-able budget: sem, each row, total."""
    return {"sem_arcsec": dict(zip(names, map(float, sem_arcsec))),
            "rows": [r.as_dict(names) for r in rows],
            "total_arcsec": dict(zip(names, total_arcsec(sem_arcsec, rows)))}


# ---------------------------------------------------------------------------------------
# Geometry
# ---------------------------------------------------------------------------------------

def _field_sensor(camera, n: int = 7) -> np.ndarray:
    """(n*n, 3) unit vectors over the image (sensor frame)."""
    xs = np.linspace(0.05, 0.95, n) * (camera.width_px - 1)
    ys = np.linspace(0.05, 0.95, n) * (camera.height_px - 1)
    xy = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2)
    v = camera.unproject(xy)
    return v[np.all(np.isfinite(v), axis=1)]


def _fit_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation R minimising ``sum |b_i - R a_i|^2`` (Kabsch / Wahba by SVD)."""
    u, _, vt = np.linalg.svd(b.T @ a)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def _usable(obs_hor: np.ndarray, model: str) -> np.ndarray:
    from shipstar.sky.refraction import min_observed_el_deg

    el = np.arcsin(np.clip(obs_hor[:, 1], -1.0, 1.0))
    return obs_hor[el > math.radians(min_observed_el_deg(model) + 0.5)]


def refraction_rotation(obs_hor, weather0, weather1, model: str, scale: float = 1.0) -> np.ndarray:
    """Rotation (hor frame) the attitude solver would add if the reference directions were
    refracted with ``weather1`` (and the refraction times ``scale``) instead of ``weather0``:
    directions ``obs_hor`` (observed with ``weather0``) are un-refracted and refracted again."""
    from shipstar.sky.refraction import refract_hor, unrefract_hor

    model_used = "erfa" if model == "none" else model
    if model == "none":                         # no refraction applied: its whole size is the error
        return refraction_rotation(obs_hor, weather0, weather1, "erfa", scale)
    true = unrefract_hor(obs_hor, weather0, model_used)
    obs1 = refract_hor(true, weather1, model_used)
    if scale != 1.0:                            # rho scaled: el_true + scale * (el_obs1 - el_true)
        el_t = np.arcsin(np.clip(true[:, 1], -1, 1))
        el_1 = np.arcsin(np.clip(obs1[:, 1], -1, 1))
        el = el_t + scale * (el_1 - el_t)
        h = np.hypot(true[:, 0], true[:, 2])
        obs1 = np.stack([np.cos(el) * true[:, 0] / h, np.sin(el), np.cos(el) * true[:, 2] / h], axis=1)
    return _fit_rotation(obs_hor, obs1)


def _refraction_rows(camera, C_hs, weather, model, sigmas: InputSigmas, humidity_given: bool):
    """[(source, sigma text, R_plus, R_minus)] for the refraction inputs."""
    obs = _usable(_field_sensor(camera) @ C_hs.T, "erfa" if model == "none" else model)
    if len(obs) < 3:
        raise ShipstarError("the sensor looks too low for a refraction uncertainty (fewer than 3 directions "
                            "of its field above the refraction model's limit)")
    h_sig = sigmas.relative_humidity if humidity_given else HUMIDITY_SIGMA_DEFAULTED
    out = []
    for source, field, sig, text in (
            ("pressure", "pressure_hpa", sigmas.pressure_hpa, f"{sigmas.pressure_hpa:g} hPa"),
            ("temperature", "temperature_c", sigmas.temperature_c, f"{sigmas.temperature_c:g} C"),
            ("humidity", "relative_humidity", h_sig,
             f"{h_sig:g}" + ("" if humidity_given else " (not given: 0 assumed)")),
            ("wavelength", "wavelength_um", sigmas.wavelength_um, f"{sigmas.wavelength_um:g} um")):
        # the almanac model ignores humidity and wavelength: their effect on the real air
        # (erfa's model) is then what the calibration does not know
        lo_hi = []
        for sgn in (1.0, -1.0):
            value = getattr(weather, field) + sgn * sig
            if field == "relative_humidity":
                value = min(max(value, 0.0), 1.0)
            w1 = replace(weather, **{field: value})
            lo_hi.append(refraction_rotation(obs, weather, w1, "erfa" if model == "none" else
                                             ("erfa" if field in ("relative_humidity", "wavelength_um")
                                              else model)))
        out.append((source, text, lo_hi[0], lo_hi[1], 1.0))
    frac = REFRACTION_MODEL_FRACTION[model]
    r_p = refraction_rotation(obs, weather, weather, model, 1.0 + frac)
    r_m = refraction_rotation(obs, weather, weather, model, 1.0 - frac)
    out.append(("refraction model", f"{frac * 100:g} % of refraction ({model})", r_p, r_m, 1.0))
    return out


def eop_rotations(utc_jd1: float, utc_jd2: float, site, obs_hor, weather, model: str, eop,
                  dut1_sigma_s: float, pm_sigma_arcsec: float):
    """[(source, sigma text, R_plus, R_minus)] for UT1 - UTC and polar motion (x, y)."""
    from shipstar.sky.apparent import frame_context
    from shipstar.sky.refraction import refract_hor, unrefract_hor

    model_used = "erfa" if model == "none" else model
    obs = _usable(np.asarray(obs_hor, float), model_used)
    true = unrefract_hor(obs, weather, model_used)
    ctx0 = frame_context(utc_jd1, utc_jd2, site, eop)
    icrs = ctx0.icrs_from_hor(true)
    out = []
    for source, field, sig, text, unit in (
            ("UT1-UTC", "dut1_s", dut1_sigma_s, f"{dut1_sigma_s:.2g} s", 1.0),
            ("polar motion x", "xp_rad", pm_sigma_arcsec, f"{pm_sigma_arcsec:.2g}''", ASEC2RAD),
            ("polar motion y", "yp_rad", pm_sigma_arcsec, f"{pm_sigma_arcsec:.2g}''", ASEC2RAD)):
        if not (math.isfinite(sig) and sig > 0):
            continue
        rots = []
        for sgn in (1.0, -1.0):
            ctx1 = frame_context(utc_jd1, utc_jd2, site, replace(eop, **{field: getattr(eop, field) + sgn * sig * unit}))
            obs1 = refract_hor(ctx1.hor_from_icrs(icrs), weather, model_used)
            rots.append(_fit_rotation(obs, obs1))
        out.append((source, text, rots[0], rots[1], 1.0))
    return out


def _effect_arcsec(a0, a_plus, a_minus) -> tuple:
    """The larger one-sided change (arcsec) of three angles: a finite difference that
    keeps the curvature (refraction is not linear in the wavelength), and a one-sided
    one where an input is clipped at its range (humidity 0)."""
    a0 = np.asarray(a0, float)
    d = [(np.asarray(a, float) - a0 + math.pi) % (2.0 * math.pi) - math.pi for a in (a_plus, a_minus)]
    return tuple(float(x) for x in np.maximum(np.abs(d[0]), np.abs(d[1])) * RAD2ASEC)


def installation_budget(camera, C_hor_from_sensor, dock, weather, model: str, sigmas: InputSigmas, *,
                        utc_jd1: float, utc_jd2: float, site, eop, dut1_sigma_s: float,
                        pm_sigma_arcsec: float, humidity_given: bool) -> list:
    """Effects on the installation angles (az, el, roll), arcsec, of each input's sigma at
    the session's mean sensor attitude ``C_hor_from_sensor`` (dock attitude ``dock``:
    :class:`~shipstar.calibrate.installation.DockConditions`)."""
    C_hs = np.asarray(C_hor_from_sensor, float)
    C_hd = dock.C_hor_from_deck

    def angles(C_hd_, C_hs_):
        return installation_angles_from_C_deck_from_sensor(C_hd_.T @ C_hs_)

    rows = []
    obs = _field_sensor(camera) @ C_hs.T
    for source, text, r_p, r_m, f in (_refraction_rows(camera, C_hs, weather, model, sigmas, humidity_given)
                                       + eop_rotations(utc_jd1, utc_jd2, site, obs, weather, model, eop,
                                                       dut1_sigma_s, pm_sigma_arcsec)):
        eff = _effect_arcsec(angles(C_hd, C_hs), angles(C_hd, r_p @ C_hs), angles(C_hd, r_m @ C_hs))
        rows.append(BudgetRow(source, text, tuple(e * f for e in eff)))
    k, p, r = dock.heading_rad, dock.pitch_rad, dock.roll_rad
    for source, sig, dk, dp, dr in (("dock heading", sigmas.heading_arcsec, 1, 0, 0),
                                    ("dock level (pitch)", sigmas.level_arcsec, 0, 1, 0),
                                    ("dock level (roll)", sigmas.level_arcsec, 0, 0, 1)):
        s = sig * ASEC2RAD
        a_p = angles(C_hor_from_deck(k + dk * s, p + dp * s, r + dr * s), C_hs)
        a_m = angles(C_hor_from_deck(k - dk * s, p - dp * s, r - dr * s), C_hs)
        rows.append(BudgetRow(source, f"{sig:g}''", _effect_arcsec(angles(C_hd, C_hs), a_p, a_m)))
    return rows


def ship_budget(camera, installation, weather, model: str, sigmas: InputSigmas, *, utc_jd1: float,
                utc_jd2: float, site, eop, dut1_sigma_s: float, pm_sigma_arcsec: float,
                humidity_given: bool) -> list:
    """Effects on the ship's (heading, pitch, roll), arcsec, of one sensor's inputs at sea:
    refraction inputs and Earth orientation as for the dock, and the installation's own
    total uncertainty (else its sem).  A level ship; refraction effects do not depend on
    the heading, Earth orientation effects do: the largest over 8 headings is taken."""
    from shipstar.frames import C_deck_from_sensor as _C_ds

    C_ds = installation.C_deck_from_sensor
    rows = []

    def ship(C):
        return ship_angles_from_C_hor_from_deck(C)

    C_hd0 = C_hor_from_deck(0.0, 0.0, 0.0)
    C_hs0 = C_hd0 @ C_ds
    for source, text, r_p, r_m, f in _refraction_rows(camera, C_hs0, weather, model, sigmas, humidity_given):
        eff = _effect_arcsec(ship(C_hd0), ship(r_p @ C_hd0), ship(r_m @ C_hd0))
        rows.append(BudgetRow(source, text, tuple(e * f for e in eff)))
    worst: dict = {}
    for heading in np.radians(np.arange(0.0, 360.0, 45.0)):
        C_hd = C_hor_from_deck(heading, 0.0, 0.0)
        obs = _field_sensor(camera) @ (C_hd @ C_ds).T
        for source, text, r_p, r_m, f in eop_rotations(utc_jd1, utc_jd2, site, obs, weather, model, eop,
                                                       dut1_sigma_s, pm_sigma_arcsec):
            eff = np.array(_effect_arcsec(ship(C_hd), ship(r_p @ C_hd), ship(r_m @ C_hd)))
            prev = worst.get(source, (text, np.zeros(3)))[1]
            worst[source] = (text, np.maximum(prev, eff))
    rows += [BudgetRow(s, t, tuple(map(float, e))) for s, (t, e) in worst.items()]
    tot = getattr(installation, "total_arcsec", None)
    sig = tot if tot is not None and all(math.isfinite(x) for x in tot) else installation.sem_arcsec
    if all(math.isfinite(x) for x in sig):
        a, e, g = installation.az_rad, installation.el_rad, installation.roll_rad
        for name, k in (("installation az", 0), ("installation el", 1), ("installation roll", 2)):
            d = np.zeros(3)
            d[k] = sig[k] * ASEC2RAD
            p_ = ship(C_hs0 @ _C_ds(a + d[0], e + d[1], g + d[2]).T)
            m_ = ship(C_hs0 @ _C_ds(a - d[0], e - d[1], g - d[2]).T)
            rows.append(BudgetRow(name, f"{sig[k]:.3g}''", _effect_arcsec(ship(C_hd0), p_, m_)))
    return rows
