"""Epochs of a session: frames of all sensors paired by time, carried to a common time, fused.

Epoch times are the reference sensor's frame times.  For each other sensor the nearest
frame within ``max_pair_offset_s`` is paired and carried to the epoch time with the deck
rate (:mod:`shipstar.pipeline._motion`).  At each epoch:

- ``single``: every sensor's ship attitude (seed 003 eq. 14-17) at the epoch time;
- ``seed_rule``: seed 003 eq. 3-5 (heading averaged, pitch from the fore-aft sensor, roll
  from the athwartship sensor);
- ``joint``: one weighted attitude solution of the deck from all sensors' stars
  (:func:`shipstar.ship.fuse_joint`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Epoch", "sensor_roles", "build_epochs"]


@dataclass(frozen=True, eq=False)
class Epoch:
    """Fused ship attitude at one reference frame time.

    Attributes
    ----------
    index : int
    utc_jd1, utc_jd2 : float
        Epoch time (the reference sensor's frame time).
    t_s : float
        Seconds since the session start.
    frame_index : tuple of int
        Paired frame of each sensor (-1: none within the pairing window).
    offset_s : tuple of float
        Paired frame time minus epoch time, per sensor (NaN: none).
    single : tuple of ShipAttitude
        Each sensor's ship attitude carried to the epoch time.
    seed_rule, joint : ShipAttitude
    """

    index: int
    utc_jd1: float
    utc_jd2: float
    t_s: float
    frame_index: tuple
    offset_s: tuple
    single: tuple
    seed_rule: object
    joint: object

    @property
    def utc_iso(self) -> str:
        from shipstar.sky.time import iso_from_utc_jd

        return iso_from_utc_jd(self.utc_jd1, self.utc_jd2, 6)


def sensor_roles(configs) -> tuple[int, int]:
    """Indices of the fore-aft and athwartship sensors (seed 003): the installations with the
    largest ``|cos A|`` and ``|sin A|``; ``(-1, -1)`` unless two different sensors qualify."""
    inst = [(i, c.installation) for i, c in enumerate(configs) if c.installation is not None]
    if len(inst) < 2:
        return -1, -1
    fore = max(inst, key=lambda p: abs(math.cos(p[1].az_rad)))[0]
    athw = max(inst, key=lambda p: abs(math.sin(p[1].az_rad)))[0]
    return (fore, athw) if fore != athw else (-1, -1)


def _pair(t_ref: float, times: np.ndarray, window_s: float) -> int:
    if len(times) == 0:
        return -1
    k = int(np.argmin(np.abs(times - t_ref)))
    return k if abs(times[k] - t_ref) <= window_s + 1e-9 else -1


def _sensor_correction(C_ds: np.ndarray, delta_deck: np.ndarray) -> np.ndarray:
    """Turn a sensor's measured vectors from its frame time to the epoch time:
    ``w' = C_ds^T Delta^T C_ds w``."""
    return C_ds.T @ delta_deck.T @ C_ds


def _carried_single(fr, config, delta_deck):
    """The frame's single-sensor ship attitude carried by the deck rotation ``delta_deck``."""
    from shipstar.ship import ShipAttitude, ship_attitude_from_sensor

    if not fr.ship.solved:
        return fr.ship
    if config.installation is None:
        return ShipAttitude.failed("no installation", "single")
    C_ds = config.installation.C_deck_from_sensor
    C_hs = fr.horizontal.C_hor_from_sensor @ _sensor_correction(C_ds, delta_deck).T
    return ship_attitude_from_sensor(C_hs, C_ds, fr.horizontal.covariance_rad2, n_stars=fr.horizontal.n_used)


def _fuse(paired, configs, roles, deltas):
    """(seed_rule, joint) from the paired FrameResults (None: no frame)."""
    from shipstar.ship import ShipAttitude, fuse_joint, fuse_seed_rule

    names = [c.name for c in configs]
    missing = [n for n, fr in zip(names, paired) if fr is None]
    failed = [f"{fr.sensor} frame {fr.label}: {fr.reason}" for fr in paired if fr is not None and not fr.solved]
    no_inst = [c.name for c in configs if c.installation is None]
    why = (f"no {', '.join(missing)} frame within the pairing window" if missing else
           "; ".join(failed) if failed else f"no installation for {', '.join(no_inst)}" if no_inst else "")
    if why:
        return ShipAttitude.failed(why, "seed-rule"), ShipAttitude.failed(why, "joint")
    singles = [_carried_single(fr, c, d) for fr, c, d in zip(paired, configs, deltas)]
    fore, athw = roles
    seed = (fuse_seed_rule(singles[fore], singles[athw]) if fore >= 0 else
            ShipAttitude.failed("the seed's rule needs a fore-aft and an athwartship sensor", "seed-rule"))
    stars = [fr.sensor_stars(c.installation.C_deck_from_sensor,
                             _sensor_correction(c.installation.C_deck_from_sensor, d))
             for fr, c, d in zip(paired, configs, deltas)]
    return seed, fuse_joint(stars)


def build_epochs(configs, results, times_s, start_jd, deck_rate, options, reference: int = 0) -> tuple:
    """Pair, carry and fuse: one :class:`Epoch` per frame of the reference sensor.

    Parameters
    ----------
    configs : sequence of SensorConfig
    results : sequence (per sensor) of sequences of FrameResult
    times_s : sequence (per sensor) of arrays (M_s,)
        Frame times, seconds since ``start_jd``.
    start_jd : (float, float)
    deck_rate : DeckRate
    options : PipelineOptions
    reference : int
        Index of the reference sensor.
    """
    from shipstar.ship import ShipAttitude

    roles = sensor_roles(configs)
    epochs = []
    for k, t in enumerate(times_s[reference]):
        idx = [k if s == reference else _pair(t, times_s[s], options.max_pair_offset_s) for s in range(len(configs))]
        paired = [results[s][i] if i >= 0 else None for s, i in enumerate(idx)]
        offsets = [float(times_s[s][i] - t) if i >= 0 else math.nan for s, i in enumerate(idx)]
        comp = options.compensate_motion
        deltas = [deck_rate.rotation(t + dt, t) if (comp and i >= 0) else np.eye(3) for dt, i in zip(offsets, idx)]
        singles = tuple(_carried_single(fr, c, d) if fr is not None else
                        ShipAttitude.failed("no frame within the pairing window", "single")
                        for fr, c, d in zip(paired, configs, deltas))
        seed, joint = _fuse(paired, configs, roles, deltas)
        jd1, jd2 = start_jd[0], start_jd[1] + t / 86400.0
        epochs.append(Epoch(k, jd1, jd2, float(t), tuple(idx), tuple(offsets), singles, seed, joint))
    return tuple(epochs)
