"""Error model of ship attitude from a star sensor, and installation layout analysis.

How errors of the sensor's horizontal attitude (As, Es, gs) and of its installation
angles (A0, E0, g0) become heading, pitch and roll errors (seed 001), validated by Monte
Carlo through the nonlinear chain; seed 001's sensitivity sweeps and conclusions; and
the installation azimuth/elevation of one or two sensors that minimises the predicted
ship attitude error.  See ``docs/error-model.md``.

Depends only on :mod:`shipstar.frames`, :mod:`shipstar.units` and :mod:`shipstar.errors`;
matplotlib is imported only by the plotting functions.
"""

from __future__ import annotations

from ._budget import ErrorBudget, MonteCarloCheck, error_budget, monte_carlo_check
from ._jacobian import (
    CONVENTIONS, OUTPUTS, PARAMS, C_hor_from_sensor_angles, angle_rate_matrix, inverse_angle_rate_matrix,
    propagate_covariance, ship_angles_rad, ship_jacobian, ship_jacobian_sensor_axes, ship_matrix,
)
from ._layout import OBJECTIVES, LayoutResult, layout_objective, optimise_layout, ship_covariance
from ._plot import plot_layout, plot_sweep
from ._seed001 import MODELS, Conclusion, check_seed001_conclusions, conclusions_markdown, trend
from ._sensor import SensorAccuracy, expected_star_count, fov_solid_angle_sr, sensor_accuracy
from ._sweep import (
    SEED001_A0_CURVES_DEG, SEED001_ALL_ERRORS_ARCSEC, SEED001_BASE_DEG, SEED001_FIGURES,
    SEED001_HEADLINE_ARCSEC, SEED001_RANGES_DEG, SEED001_ROLL_ONLY_ERRORS_ARCSEC, HeadlineCheck,
    SeedFigure, SweepMax, SweepResult, seed001_headline, seed001_sweep, sweep,
)

__all__ = [
    # observation model and Jacobian
    "PARAMS", "OUTPUTS", "CONVENTIONS", "C_hor_from_sensor_angles", "ship_matrix", "ship_angles_rad",
    "angle_rate_matrix", "inverse_angle_rate_matrix", "ship_jacobian", "ship_jacobian_sensor_axes",
    "propagate_covariance",
    # budgets and Monte Carlo
    "ErrorBudget", "error_budget", "MonteCarloCheck", "monte_carlo_check",
    # seed 001 sweeps, headline, conclusions
    "SEED001_BASE_DEG", "SEED001_A0_CURVES_DEG", "SEED001_RANGES_DEG", "SEED001_ROLL_ONLY_ERRORS_ARCSEC",
    "SEED001_ALL_ERRORS_ARCSEC", "SEED001_HEADLINE_ARCSEC", "SEED001_FIGURES", "SeedFigure",
    "SweepResult", "sweep", "seed001_sweep", "SweepMax", "HeadlineCheck", "seed001_headline",
    "MODELS", "Conclusion", "trend", "check_seed001_conclusions", "conclusions_markdown",
    # sensor accuracy and layout
    "SensorAccuracy", "sensor_accuracy", "expected_star_count", "fov_solid_angle_sr",
    "OBJECTIVES", "ship_covariance", "layout_objective", "LayoutResult", "optimise_layout",
    # plots
    "plot_sweep", "plot_layout",
]
