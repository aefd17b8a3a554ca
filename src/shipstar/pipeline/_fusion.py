"""One epoch: the sensors' paired frames carried to a common time and fused.

Epoch times are the reference sensor's frame times.  For each other sensor the nearest
frame within ``max_pair_offset_s`` is paired (:mod:`shipstar.pipeline._engine` decides
which) and carried to the epoch time with the deck's motion fitted to the frames
(:mod:`shipstar.pipeline._motion`).  At each epoch:

- ``single``: every sensor's ship attitude (seed 003 eq. 14-17) at the epoch time;
- ``seed_rule``: seed 003 eq. 3-5 (heading averaged, pitch from the fore-aft sensor, roll
  from the athwartship sensor);
- ``joint``: one weighted attitude solution of the deck from all sensors' stars
  (:func:`shipstar.ship.fuse_joint`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

__all__ = ["Epoch", "sensor_roles", "fuse_epoch", "MIN_CARRY_S"]

#: Paired frames closer in time than this (s) are fused without a carry (1 us: 0.014'' at 4 deg/s).
MIN_CARRY_S = 1e-6


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
    label : str
        The reference frame's label.
    time_source : str
        How the reference frame's time was found in its file.
    integrity : Integrity
        The sensors' deck attitudes checked against each other
        (:mod:`shipstar.pipeline._integrity`).
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
    label: str = ""
    time_source: str = ""
    integrity: object = None
    mounts: object = None            # pipeline._mounts.MountsSnapshot: clock offsets and flexure

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


def _sensor_correction(C_ds: np.ndarray, delta_deck: np.ndarray) -> np.ndarray:
    """Turn a sensor's measured vectors from its frame time to the epoch time:
    ``w' = C_ds^T Delta^T C_ds w``."""
    return C_ds.T @ delta_deck.T @ C_ds


def _carried_single(fr, config, delta_deck, variance_factor: float = 1.0):
    """The frame's single-sensor ship attitude carried by the deck rotation ``delta_deck``,
    its stars' covariance times ``variance_factor``."""
    from shipstar.ship import ShipAttitude, ship_attitude_from_sensor

    if not fr.ship.solved:
        return fr.ship
    if config.installation is None:
        return ShipAttitude.failed("no installation", "single")
    C_ds = config.installation.C_deck_from_sensor
    C_hs = fr.horizontal.C_hor_from_sensor @ _sensor_correction(C_ds, delta_deck).T
    cov = np.asarray(fr.horizontal.covariance_rad2, float) * variance_factor
    M = getattr(config.installation, "mount_covariance_rad2", None)
    if M is not None:               # a flexed mount's uncertainty (deck axes) in the sensor's axes
        cov = np.asarray(cov, float) + C_ds.T @ M @ C_ds
    return ship_attitude_from_sensor(C_hs, C_ds, cov, n_stars=fr.horizontal.n_used)


def _fuse(paired, configs, roles, deltas, singles, carry_why: str = "", variance_factor: float = 1.0):
    """(seed_rule, joint) from the paired FrameResults (None: no frame) and their carried
    single-sensor attitudes; ``carry_why``: why the frames cannot be carried ('' if they can)."""
    from shipstar.ship import ShipAttitude, fuse_joint, fuse_seed_rule

    names = [c.name for c in configs]
    missing = [n for n, fr in zip(names, paired) if fr is None]
    failed = [f"{fr.sensor} frame {fr.label}: {fr.reason}" for fr in paired if fr is not None and not fr.solved]
    no_inst = [c.name for c in configs if c.installation is None]
    why = (f"no {', '.join(missing)} frame within the pairing window" if missing else
           "; ".join(failed) if failed else f"no installation for {', '.join(no_inst)}" if no_inst else carry_why)
    if why:
        return ShipAttitude.failed(why, "seed-rule"), ShipAttitude.failed(why, "joint")
    fore, athw = roles
    seed = (fuse_seed_rule(singles[fore], singles[athw]) if fore >= 0 else
            ShipAttitude.failed("the seed's rule needs a fore-aft and an athwartship sensor", "seed-rule"))
    stars = [fr.sensor_stars(c.installation.C_deck_from_sensor,
                             _sensor_correction(c.installation.C_deck_from_sensor, d))
             for fr, c, d in zip(paired, configs, deltas)]
    if variance_factor != 1.0:
        stars = [replace(s, sigma_rad=np.asarray(s.sigma_rad, float) * math.sqrt(variance_factor),
                         info_per_rad2=None if s.info_per_rad2 is None else s.info_per_rad2 / variance_factor)
                 for s in stars]
    # flexed mounts (pipeline._mounts): the estimate's uncertainty weights the sensor
    stars = [s if getattr(c.installation, "mount_covariance_rad2", None) is None else
             replace(s, mount_covariance_rad2=c.installation.mount_covariance_rad2)
             for s, c in zip(stars, configs)]
    return seed, fuse_joint(stars)


def _deltas(offsets_s, t_s: float, motion, options):
    """Deck rotations carrying each paired frame to the epoch time (identity for frames at
    the epoch time or without a pair), or a reason why they cannot be carried."""
    from shipstar.pipeline._motion import MIN_MOTION_SAMPLES, MOTION_WINDOW_S

    deltas = [np.eye(3)] * len(offsets_s)
    carried = [k for k, dt in enumerate(offsets_s) if math.isfinite(dt) and abs(dt) > MIN_CARRY_S]
    if not options.compensate_motion or not carried:
        return deltas, ""
    if motion is None:
        return deltas, f"the deck's motion is not known yet (fewer than {MIN_MOTION_SAMPLES} solved frames within {MOTION_WINDOW_S:g} s)"
    for k in carried:
        deltas[k] = motion.rotation(t_s + offsets_s[k], t_s)
    return deltas, ""


def fuse_epoch(index: int, t_s: float, start_jd, configs, paired, offsets_s, motion, options, roles=None, *,
               reference: int = 0, variance_factor: float = 1.0) -> Epoch:
    """Carry and fuse one epoch.

    Parameters
    ----------
    index : int
        Epoch number.
    t_s : float
        Epoch time (the reference frame's), seconds since ``start_jd``.
    start_jd : (float, float)
    configs : sequence of SensorConfig
    paired : sequence (per sensor) of FrameResult or None
        The frame of each sensor paired to the epoch (None: none within the window).
    offsets_s : sequence of float
        Paired frame time minus epoch time, per sensor (NaN without a frame).
    motion : MotionFit or None
        The deck's motion (``C_hor_from_deck``) around the epoch.
    options : PipelineOptions
    roles : (int, int), optional
        :func:`sensor_roles` of ``configs``.
    reference : int
        Index of the reference sensor (its frame gives the epoch's label).
    variance_factor : float
        Multiplies the stars' covariances (the sensors' a posteriori variance factor from
        their disagreement, :meth:`shipstar.pipeline._mounts.MountEstimator.variance_factor`).

    Returns
    -------
    Epoch
    """
    from shipstar.pipeline._integrity import epoch_integrity
    from shipstar.ship import ShipAttitude

    roles = sensor_roles(configs) if roles is None else roles
    deltas, why = _deltas(offsets_s, t_s, motion, options)
    singles = []
    for fr, c, d, dt in zip(paired, configs, deltas, offsets_s):
        if fr is None:
            singles.append(ShipAttitude.failed("no frame within the pairing window", "single"))
        elif why and abs(dt) > MIN_CARRY_S:
            singles.append(ShipAttitude.failed(why, "single"))
        else:
            singles.append(_carried_single(fr, c, d, variance_factor))
    seed, joint = _fuse(paired, configs, roles, deltas, singles, why, variance_factor)
    integrity = epoch_integrity(configs, paired, singles)
    singles = tuple(singles)
    frame_index = tuple(fr.index if fr is not None else -1 for fr in paired)
    ref = paired[reference]
    return Epoch(index, start_jd[0], start_jd[1] + t_s / 86400.0, float(t_s), frame_index,
                 tuple(float(x) for x in offsets_s), singles, seed, joint, ref.label, ref.time_source, integrity)
