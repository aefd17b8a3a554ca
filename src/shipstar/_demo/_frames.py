"""Simulated frames of one sensor, made on demand: image level (rendered) or centroid level.

Image level: :func:`shipstar.simulate.simulate_frame` renders the raw frame (PSF, noise,
hot pixels, motion smear from the ship's rate; the session's ``exposure_s`` if set); the
pipeline extracts, identifies and solves it like a FITS frame.  Centroid level: the catalog stars' true image positions
with Gaussian centroid noise and no identities (the pipeline still identifies them).
Frames are made one chunk at a time so that a session never holds more than a chunk of
1024 x 1024 images in memory.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SimFrame", "make_frame", "frame_seed", "n_image_level"]


@dataclass(frozen=True, eq=False)
class SimFrame:
    """One simulated frame and its truth.

    Attributes
    ----------
    sensor : str
    index : int
    t_s : float
        Mid-exposure time since the session start.
    frame : shipstar.pipeline.Frame
        What the pipeline gets (image or centroids, never the identities).
    image_level : bool
    simulated : shipstar.simulate.SimulatedFrame or None
        The rendered frame (image level only).
    C_hor_from_sensor : (3, 3)
        True sensor attitude.
    """

    sensor: str
    index: int
    t_s: float
    frame: object
    image_level: bool
    simulated: object
    C_hor_from_sensor: np.ndarray


def frame_seed(spec, sensor_index: int, k: int) -> int:
    """Noise seed of frame ``k`` of a sensor (independent streams, reproducible)."""
    return int(np.random.SeedSequence([spec.seed, sensor_index, k]).generate_state(1, np.uint64)[0]) >> 1


def _image_frame(spec, j: int, s, k: int, t: float, label: str) -> SimFrame:
    from shipstar.pipeline import Frame
    from shipstar.simulate import ShipPose, simulate_frame

    K, psi, theta = (float(a) for a in spec.motion.angles_rad(t))
    pose = ShipPose(K, psi, theta, s.install_az_rad, s.install_el_rad, s.install_roll_rad)
    omega = pose.omega_sensor_from_deck(spec.motion.omega_deck_rad_per_s(t))
    camera = s.camera if spec.exposure_s is None else s.camera.replace(exposure_s=spec.exposure_s)
    sim = simulate_frame(camera, ship=pose, utc_iso=spec.utc_iso(t), site=spec.site(t), weather=spec.weather(t),
                         refraction_model=spec.refraction_model, mag_limit=spec.mag_limit,
                         seed=frame_seed(spec, j, k), omega_sensor_rad_per_s=omega)
    frame = Frame(sim.utc_jd1, sim.utc_jd2, label, image=sim.image)
    return SimFrame(s.name, k, t, frame, True, sim, pose.C_hor_from_sensor)


def _centroid_frame(spec, j: int, s, k: int, t: float, label: str) -> SimFrame:
    from shipstar.pipeline import Frame
    from shipstar.simulate import simulate_stars_horizontal
    from shipstar.sky.apparent import frame_context

    jd1, jd2 = spec.utc_jd(t)
    C_hs = spec.motion.C_hor_from_deck(t) @ s.C_deck_from_sensor
    stars = simulate_stars_horizontal(s.camera, C_hs, frame_context(jd1, jd2, spec.site(t)), spec.weather(t),
                                      spec.refraction_model, mag_limit=spec.mag_limit)
    rng = np.random.default_rng(frame_seed(spec, j, k))
    xy = stars.xy_px + rng.normal(0.0, spec.centroid_sigma_px, stars.xy_px.shape)
    frame = Frame.from_centroids(jd1, jd2, xy, None, label)
    return SimFrame(s.name, k, t, frame, False, None, C_hs)


def n_image_level(spec, image_level_s: float) -> int:
    """Frames (per sensor, by index) rendered as images: those of the first sensor's
    clock before ``image_level_s``."""
    return int(np.count_nonzero(spec.times_s(spec.sensors[0]) < image_level_s))


def make_frame(spec, sensor_index: int, k: int, image_level: bool) -> SimFrame:
    """Frame ``k`` of sensor ``sensor_index`` of a :class:`~shipstar.simulate._session.SessionSpec`."""
    s = spec.sensors[sensor_index]
    t = float(spec.times_s(s)[k])
    make = _image_frame if image_level else _centroid_frame
    return make(spec, sensor_index, s, k, t, f"{s.name}_{k:05d}")
