"""Synthetic star-sensor frames with known truth (the scene simulator).

Geometry (``docs/simulation.md``)::

    simulate_stars(camera, C_icrs_from_sensor, *, epoch_jyear, mag_limit)     # "space"
    simulate_stars_horizontal(camera, C_hor_from_sensor, context, weather,    # on Earth:
                              refraction_model, *, mag_limit)                 # apparent places + refraction
        -> SimulatedStars (hip, xy_px, mag, u_sensor, signal_e, smear_px, v_ref, ...)
    smear_px_from_rate(camera, u_sensor, omega_sensor_rad_per_s, exposure_s)  # motion smear

Images and files::

    render(camera, stars, rng, *, false_objects, hot_pixel_fraction) -> (H, W) uint16
    random_false_objects(camera, rng, *, planets, trails, cosmic_rays) -> FalseObjects
    simulate_frame(camera, *, C_icrs_from_sensor | C_hor_from_sensor | ship=ShipPose, utc_iso,
                   site, weather, refraction_model, mag_limit, seed, ...) -> SimulatedFrame
    write_frame(frame, "x.fits") -> (x.fits, x.truth.json);  read_truth(path) -> dict

Image formation itself (PSF, noise, ADC) is in ``shipstar.simulate._render``.
"""

from __future__ import annotations

from shipstar.simulate._fits import TRUTH_SCHEMA, image_sha256, read_truth, truth_dict, truth_path_for, write_frame
from shipstar.simulate._frame import (
    HOT_PIXEL_FRACTION,
    J2000_UTC_ISO,
    ShipPose,
    SimulatedFrame,
    hot_pixel_seed,
    random_false_objects,
    render,
    simulate_frame,
)
from shipstar.simulate._motion import EARTH_RATE_RAD_PER_S, earth_rate_hor_rad_per_s, smear_px_from_rate
from shipstar.simulate._render import FalseObjects
from shipstar.simulate._scene import DEFAULT_MAG_LIMIT, SimulatedStars, simulate_stars, simulate_stars_horizontal

__all__ = [
    "SimulatedStars", "simulate_stars", "simulate_stars_horizontal", "DEFAULT_MAG_LIMIT",
    "smear_px_from_rate", "earth_rate_hor_rad_per_s", "EARTH_RATE_RAD_PER_S",
    "FalseObjects", "random_false_objects", "render", "hot_pixel_seed", "HOT_PIXEL_FRACTION",
    "ShipPose", "SimulatedFrame", "simulate_frame", "J2000_UTC_ISO",
    "write_frame", "read_truth", "truth_dict", "truth_path_for", "image_sha256", "TRUTH_SCHEMA",
]
