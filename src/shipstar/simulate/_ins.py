"""A simulated inertial navigator (INS) on the simulated ship: its attitude log (issue 15).

The INS samples on its own clock at ``rate_hz``: record ``k`` is stamped
``tau_k = tau_0 + k / rate_hz`` (INS clock, s since the session start), taken at the true
(frame-clock) time ``t_k = tau_k - time_offset_s`` (so ``time_offset_s`` is the INS clock
minus the frames' clock).  Its reading is the INS body's attitude plus its errors:

``reading(t) = angles(C_hor_from_deck(t) @ C_deck_from_ins) + [b_h + d (t - t_0) + w_h(t), b_p + w_p(t),
b_r + w_r(t)] + white noise``, quantised to ``quantisation_deg``,

with ``C_deck_from_ins = exp([m x])`` (``m`` = ``misalignment_arcsec``, deck axes bow / up /
starboard), ``b`` the biases at the first record, ``d`` the heading drift, ``w`` random
walks (``*_random_walk_arcsec_per_sqrt_h``).  INS error = INS reading minus truth.

Written as CSV (``time_utc, heading_deg, pitch_deg, roll_deg, heading_rate_deg_per_s,
pitch_rate_deg_per_s, roll_rate_deg_per_s``, INS clock) and as NMEA 0183 (per record
``$GPZDA`` with the time, ``$PASHR``, ``$HEHDT`` and Seapath's ``$PSXN,23``), each in a
chosen sign convention (:class:`shipstar.frames.AttitudeConvention`), and the true error
terms as JSON.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, fields

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.units import ASEC2RAD, DEG2RAD, RAD2DEG

__all__ = ["InsErrors", "InsLogTruth", "simulate_ins", "write_ins_files", "parse_ins_errors"]

_H_S = 3600.0


@dataclass(frozen=True)
class InsErrors:
    """A simulated INS's errors (defaults: issue 15's benchmark: a good marine fibre-optic INS).

    Attributes
    ----------
    heading_bias_arcsec, pitch_bias_arcsec, roll_bias_arcsec : float
        At the first record.
    heading_drift_arcsec_per_h : float
    heading_random_walk_arcsec_per_sqrt_h, level_random_walk_arcsec_per_sqrt_h : float
        Random walk of the heading error and of the pitch and roll errors.
    noise_arcsec : float
        White noise per sample and angle.
    quantisation_deg : float
        Resolution of the readings (0: none).
    misalignment_arcsec : (3,) float
        INS body to deck rotation vector, deck axes bow / up / starboard.
    time_offset_s : float
        INS clock minus the frames' clock.
    rate_hz : float
        Records per second.
    seed : int
    """

    heading_bias_arcsec: float = 30.0
    heading_drift_arcsec_per_h: float = 36.0
    pitch_bias_arcsec: float = 5.0
    roll_bias_arcsec: float = 5.0
    heading_random_walk_arcsec_per_sqrt_h: float = 3.6
    level_random_walk_arcsec_per_sqrt_h: float = 1.0
    noise_arcsec: float = 0.5
    quantisation_deg: float = 1e-5
    misalignment_arcsec: tuple = (0.0, 0.0, 0.0)
    time_offset_s: float = 0.02
    rate_hz: float = 50.0
    seed: int = 1

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            vals = v if f.name == "misalignment_arcsec" else (v,)
            if f.name == "misalignment_arcsec" and len(vals) != 3:
                raise ShipstarError(f"INS misalignment_arcsec needs 3 values (bow, up, starboard), got {v!r}")
            for x in vals:
                if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                    raise ShipstarError(f"INS {f.name} must be a finite number, got {x!r}")
        if self.rate_hz <= 0 or self.rate_hz > 1000:
            raise ShipstarError(f"INS rate_hz must be within (0, 1000], got {self.rate_hz!r}")
        if abs(self.time_offset_s) > 10.0:
            raise ShipstarError(f"INS time_offset_s must be within +-10 s, got {self.time_offset_s!r}")
        for name in ("noise_arcsec", "quantisation_deg", "heading_random_walk_arcsec_per_sqrt_h",
                     "level_random_walk_arcsec_per_sqrt_h"):
            if getattr(self, name) < 0:
                raise ShipstarError(f"INS {name} must be >= 0, got {getattr(self, name)!r}")


def parse_ins_errors(text: str) -> InsErrors:
    """``"heading_bias_arcsec=30,time_offset_s=0.02,misalignment_arcsec=10/-5/3"`` -> InsErrors
    (anything not named keeps its default)."""
    names = {f.name for f in fields(InsErrors)}
    kw = {}
    for part in (p.strip() for p in str(text or "").split(",")):
        if not part:
            continue
        key, sep, value = (s.strip() for s in part.partition("="))
        if not sep or key not in names:
            raise ShipstarError(f"INS error term {part!r}: write name=value with a name among {', '.join(sorted(names))}")
        try:
            if key == "misalignment_arcsec":
                kw[key] = tuple(float(x) for x in value.split("/"))
            elif key == "seed":
                kw[key] = int(value)
            else:
                kw[key] = float(value)
        except ValueError:
            raise ShipstarError(f"INS error term {part!r}: {value!r} is not a number") from None
    return InsErrors(**kw)


@dataclass(frozen=True, eq=False)
class InsLogTruth:
    """A simulated INS log and its truth.

    Attributes
    ----------
    tau_s : (N,)
        Record times on the INS clock (s since the session start).
    t_s : (N,)
        True (frame-clock) times of the records: ``tau_s - time_offset_s``.
    reading_rad : (N, 3)
        INS heading (in [0, 2 pi)), pitch, roll as shipstar's conventions.
    rate_rad_per_s : (N, 3)
        Their rates (of the true attitude).
    error_rad : (N, 3)
        INS reading minus truth (heading wrapped to +-pi).
    errors : InsErrors
    slow_error_rad : (N, 3) or None
        The error without the white noise and the quantisation (bias, drift, random walk,
        misalignment).
    """

    tau_s: np.ndarray
    t_s: np.ndarray
    reading_rad: np.ndarray
    rate_rad_per_s: np.ndarray
    error_rad: np.ndarray
    errors: InsErrors = field(default_factory=InsErrors)
    slow_error_rad: np.ndarray | None = None


def _expm(phi) -> np.ndarray:
    phi = np.asarray(phi, float)
    a = float(np.linalg.norm(phi))
    if a == 0.0:
        return np.eye(3)
    k = phi / a
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(a) * K + (1.0 - math.cos(a)) * (K @ K)


def _true_angles(motion, t_s, C_deck_from_ins):
    from shipstar.frames import ship_angles_from_C_hor_from_deck

    K, p, r = ship_angles_from_C_hor_from_deck(motion.C_hor_from_deck(t_s) @ C_deck_from_ins)
    return np.stack([K, p, r], -1)


def simulate_ins(spec, errors: InsErrors | None = None, *, t0_s: float = -1.0, t1_s: float | None = None) -> InsLogTruth:
    """The INS log of a simulated session ``spec`` (a ``SessionSpec``) from INS-clock time
    ``t0_s`` to ``t1_s`` (default: the session's duration + 1 s)."""
    e = InsErrors() if errors is None else errors
    t1 = spec.duration_s + 1.0 if t1_s is None else float(t1_s)
    n = int(math.floor((t1 - t0_s) * e.rate_hz + 1e-9)) + 1
    tau = np.round((t0_s + np.arange(n) / e.rate_hz) * 1e6) / 1e6          # whole microseconds, as written
    t = tau - e.time_offset_s
    rng = np.random.default_rng([e.seed, 15])
    C_di = _expm(np.asarray(e.misalignment_arcsec, float) * ASEC2RAD)
    truth = np.stack(spec.motion.angles_rad(t), -1)
    body = _true_angles(spec.motion, t, C_di)
    h = 1e-3
    d = (_true_angles(spec.motion, t + h, np.eye(3)) - _true_angles(spec.motion, t - h, np.eye(3)))
    d[:, 0] = (d[:, 0] + math.pi) % (2 * math.pi) - math.pi
    rate = d / (2 * h)
    dt = 1.0 / e.rate_hz
    steps = rng.normal(0.0, 1.0, (n, 3)) * math.sqrt(dt / _H_S)
    steps[0] = 0.0
    walk = np.cumsum(steps, 0) * np.array([e.heading_random_walk_arcsec_per_sqrt_h, e.level_random_walk_arcsec_per_sqrt_h,
                                           e.level_random_walk_arcsec_per_sqrt_h])
    err_asec = walk + np.array([e.heading_bias_arcsec, e.pitch_bias_arcsec, e.roll_bias_arcsec])
    err_asec[:, 0] += e.heading_drift_arcsec_per_h * (t - t[0]) / _H_S
    slow = body + err_asec * ASEC2RAD - truth
    slow[:, 0] = (slow[:, 0] + math.pi) % (2 * math.pi) - math.pi
    err_asec += rng.normal(0.0, e.noise_arcsec, (n, 3))
    reading = body + err_asec * ASEC2RAD
    if e.quantisation_deg > 0:
        q = e.quantisation_deg * DEG2RAD
        reading = np.round(reading / q) * q
    reading[:, 0] = np.mod(reading[:, 0], 2 * math.pi)
    error = reading - truth
    error[:, 0] = (error[:, 0] + math.pi) % (2 * math.pi) - math.pi
    return InsLogTruth(tau, t, reading, rate, error, e, slow)


def _decimals(errors: InsErrors) -> int:
    q = errors.quantisation_deg
    return 7 if q <= 0 else max(2, min(9, int(math.ceil(-math.log10(q) - 1e-9))))


def write_ins_files(spec, log: InsLogTruth, out_dir, *, convention: str = "", prefix: str = "ins") -> dict:
    """Write ``OUT/ins.csv``, ``OUT/ins.nmea`` and ``OUT/ins_truth.json``; returns their paths.

    ``convention`` (:class:`shipstar.frames.AttitudeConvention`): the signs the files use
    (default shipstar's: roll positive port up, pitch positive bow up).
    """
    from pathlib import Path

    from shipstar._atomic import atomic_write_text
    from shipstar.frames import AttitudeConvention
    from shipstar.sky.time import iso_from_utc_jd

    conv = AttitudeConvention(convention)
    out = Path(out_dir)
    nd = _decimals(log.errors)
    K, p, r = conv.from_shipstar(*(log.reading_rad * RAD2DEG).T)
    Kr, pr, rr = conv.from_shipstar(*(log.rate_rad_per_s * RAD2DEG).T)
    jd1, jd2 = spec.utc_jd(0.0)
    iso = [iso_from_utc_jd(jd1, jd2 + tau / 86400.0, 6) for tau in log.tau_s]
    rows = [f"{s},{a:.{nd}f},{b:.{nd}f},{c:.{nd}f},{x:.6f},{y:.6f},{z:.6f}\n"
            for s, a, b, c, x, y, z in zip(iso, K, p, r, Kr, pr, rr)]
    csv_text = ("# shipstar simulated INS log (docs/simulation.md); INS clock; convention " + conv.text + "\n"
                "time_utc,heading_deg,pitch_deg,roll_deg,heading_rate_deg_per_s,pitch_rate_deg_per_s,"
                "roll_rate_deg_per_s\n" + "".join(rows))
    files = {"ins_csv": out / f"{prefix}.csv", "ins_nmea": out / f"{prefix}.nmea", "ins_truth": out / f"{prefix}_truth.json"}
    atomic_write_text(files["ins_csv"], csv_text)
    atomic_write_text(files["ins_nmea"], "".join(nmea_lines(iso, K, p, r, nd)))
    e = log.errors
    truth = {"format": "shipstar-ins-truth", "convention": conv.text, "errors": asdict(e),
             "heading_bias_arcsec": e.heading_bias_arcsec, "heading_drift_arcsec_per_h": e.heading_drift_arcsec_per_h,
             "pitch_bias_arcsec": e.pitch_bias_arcsec, "roll_bias_arcsec": e.roll_bias_arcsec,
             "time_offset_s": e.time_offset_s, "misalignment_arcsec": list(e.misalignment_arcsec),
             "first_record_utc": iso[0], "n_records": len(iso),
             "note": "INS error = INS reading minus truth; biases at the first record, plus random walk and noise"}
    atomic_write_text(files["ins_truth"], json.dumps(truth, indent=1) + "\n")
    return files


def _sentence(body: str) -> str:
    from functools import reduce

    return "$" + body + "*" + f"{reduce(lambda acc, ch: acc ^ ord(ch), body, 0):02X}" + "\r\n"


def nmea_lines(iso, heading_deg, pitch_deg, roll_deg, decimals: int = 5):
    """Per record: ``$GPZDA`` (time and date), ``$PASHR`` (time, heading, roll, pitch),
    ``$HEHDT`` and ``$PSXN,23`` (roll, pitch, heading, heave), angles as given."""
    nd = decimals
    for s, K, p, r in zip(iso, heading_deg, pitch_deg, roll_deg):
        date, _, clock = s.rstrip("Z").partition("T")
        y, mo, d = date.split("-")
        hms = clock[0:2] + clock[3:5] + clock[6:12]                       # hhmmss.sss
        K = K % 360.0
        yield _sentence(f"GPZDA,{clock[0:2]}{clock[3:5]}{clock[6:]},{d},{mo},{y},00,00")
        yield _sentence(f"PASHR,{hms},{K:.{nd}f},T,{r:+.{nd}f},{p:+.{nd}f},,,,,2,2")
        yield _sentence(f"HEHDT,{K:.{nd}f},T")
        yield _sentence(f"PSXN,23,{r:.{nd}f},{p:.{nd}f},{K:.{nd}f},0.00")
