"""Attitude from matched vectors (issue 4, item 4).

Wahba solvers, all returning ``C_ref_from_body`` (``v_ref = C @ w_body``) and accepting
stacks ``(..., N, 3)``:

- :func:`quest` -- QUEST with Newton's iteration ("Quest-Newton", seeds 000/003) and
  sequential rotations near 180 degrees; :func:`quest_single` is its fast path for one
  ``(N, 3)`` problem of unit vectors (no normalisation), for callers that solve many
  (star identification);
- :func:`svd_attitude` -- Markley's SVD method;
- :func:`esoq2` -- Mortari's ESOQ2.

:func:`solve_attitude` is the checked entry point: weights, covariance
(:func:`attitude_covariance`), iterative outlier rejection, ``solved``/``reason``.

Seed 004's three-star boresight (:func:`boresight_from_three_stars`,
:func:`boresight_from_three_radii`, :func:`focal_length_from_three_stars`) and its
error-bound star selection (:func:`three_star_error_bound`, :func:`best_three_stars`).

Sensor attitude in the local horizontal frame from identified stars, with per-star
(or seed 000 ref. [9] boresight-only) refraction: :func:`sensor_attitude_hor`,
:func:`sensor_attitude_hor_from_catalog` (seed 000 eq. 6-16).

See docs/attitude.md.
"""

from __future__ import annotations

from shipstar.attitude._boresight3 import (
    ThreeStarSolution,
    boresight_from_three_radii,
    boresight_from_three_stars,
    three_star_error_bound,
)
from shipstar.attitude._covariance import attitude_covariance, residuals_rad
from shipstar.attitude._esoq2 import esoq2
from shipstar.attitude._horizontal import (
    REFRACTION_MODES,
    HorizontalAttitude,
    sensor_attitude_hor,
    sensor_attitude_hor_from_catalog,
)
from shipstar.attitude._focal3 import FocalLength, focal_length_from_three_stars
from shipstar.attitude._quest import quest, quest_single
from shipstar.attitude._select3 import BestThree, all_triples, best_three_stars
from shipstar.attitude._solve import METHODS, AttitudeSolution, solve_attitude
from shipstar.attitude._svd import svd_attitude

__all__ = [
    "AttitudeSolution", "solve_attitude", "METHODS",
    "quest", "quest_single", "svd_attitude", "esoq2",
    "attitude_covariance", "residuals_rad",
    "ThreeStarSolution", "boresight_from_three_stars", "boresight_from_three_radii",
    "FocalLength", "focal_length_from_three_stars",
    "three_star_error_bound", "BestThree", "best_three_stars", "all_triples",
    "HorizontalAttitude", "sensor_attitude_hor", "sensor_attitude_hor_from_catalog", "REFRACTION_MODES",
]
