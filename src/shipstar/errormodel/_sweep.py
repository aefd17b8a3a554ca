"""Sensitivity sweeps of seed 001 (figures 1-6) and the check of its 112'' headline."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.units import DEG2RAD, RAD2DEG

from ._budget import ErrorBudget, error_budget, validate_errors_arcsec
from ._jacobian import OUTPUTS, PARAMS

__all__ = [
    "SEED001_BASE_DEG", "SEED001_A0_CURVES_DEG", "SEED001_RANGES_DEG",
    "SEED001_ROLL_ONLY_ERRORS_ARCSEC", "SEED001_ALL_ERRORS_ARCSEC", "SEED001_HEADLINE_ARCSEC",
    "SeedFigure", "SEED001_FIGURES", "SweepResult", "sweep", "seed001_sweep",
    "SweepMax", "HeadlineCheck", "seed001_headline",
]

#: Seed 001 sec. 3.1/3.2: the values of the angles that are not swept (A0 is per curve).
SEED001_BASE_DEG = {"As": 235.0, "Es": 45.0, "gs": 90.0, "A0": 0.0, "E0": 35.0, "g0": 0.0}
#: One curve per installation azimuth (every sweep except the A0 sweep).
SEED001_A0_CURVES_DEG = (0.0, 90.0, 180.0, 270.0)
#: Sweep ranges (deg) of seed 001 sec. 3.1/3.2.
SEED001_RANGES_DEG = {"As": (0.0, 360.0), "Es": (0.0, 90.0), "gs": (-90.0, 90.0),
                      "A0": (0.0, 360.0), "E0": (0.0, 90.0), "g0": (-90.0, 90.0)}
#: Sec. 3.1: only the sensor's horizontal roll is in error, by 100''.
SEED001_ROLL_ONLY_ERRORS_ARCSEC = (0.0, 0.0, 100.0, 0.0, 0.0, 0.0)
#: Sec. 3.2: dgs = 100'', dAs = dEs = 3'', dA0 = dE0 = 1'', dg0 = 20''.
SEED001_ALL_ERRORS_ARCSEC = (3.0, 3.0, 100.0, 1.0, 1.0, 20.0)
#: Seed 001's headline: a 100'' sensor roll error gives up to 112'' of heading error.
SEED001_HEADLINE_ARCSEC = 112.0


@dataclass(frozen=True)
class SeedFigure:
    """One of seed 001's sweeps: which angle is swept, with which errors."""

    key: str
    param: str
    errors_arcsec: tuple
    section: str
    caption: str


SEED001_FIGURES = (
    SeedFigure("fig1_As", "As", SEED001_ROLL_ONLY_ERRORS_ARCSEC, "3.1", "Fig. 1: effect of As (100'' roll error only)"),
    SeedFigure("fig2_Es", "Es", SEED001_ROLL_ONLY_ERRORS_ARCSEC, "3.1", "Fig. 2: effect of Es (100'' roll error only)"),
    SeedFigure("fig2_gs", "gs", SEED001_ROLL_ONLY_ERRORS_ARCSEC, "3.1",
               "Fig. 2 (gs, 'similar'): effect of gs (100'' roll error only)"),
    SeedFigure("fig2_A0", "A0", SEED001_ROLL_ONLY_ERRORS_ARCSEC, "3.1",
               "Fig. 2 (A0, 'similar'): effect of A0 (100'' roll error only)"),
    SeedFigure("fig3_E0", "E0", SEED001_ROLL_ONLY_ERRORS_ARCSEC, "3.1", "Fig. 3: effect of E0 (100'' roll error only)"),
    SeedFigure("fig4_A0", "A0", SEED001_ALL_ERRORS_ARCSEC, "3.2", "Fig. 4: effect of A0 (all errors)"),
    SeedFigure("fig5_g0", "g0", SEED001_ALL_ERRORS_ARCSEC, "3.2", "Fig. 5: effect of g0 (all errors)"),
    SeedFigure("fig6_E0", "E0", SEED001_ALL_ERRORS_ARCSEC, "3.2", "Fig. 6: effect of E0 (all errors)"),
)


@dataclass(frozen=True)
class SweepResult:
    """One angle swept over a range, one curve per installation azimuth.

    Attributes
    ----------
    param : str
        The swept angle (one of :data:`PARAMS`).
    values_deg : ndarray, shape (n,)
    curve_labels : tuple of str, length m
        ``"A0 = 90 deg"`` per curve, or ``"A0 swept"`` when A0 is the swept angle.
    budget : ErrorBudget
        Shape ``S = (m, n)``: contributions, RSS, signed sum, gimbal-lock flags.
    convention : str
    lock_margin_deg : float
    """

    param: str
    values_deg: np.ndarray
    curve_labels: tuple
    budget: ErrorBudget
    convention: str
    lock_margin_deg: float

    @property
    def n_gimbal_locked(self) -> int:
        return int(np.count_nonzero(self.budget.gimbal_locked))

    def max_abs(self, output: str, kind: str = "rss") -> "SweepMax":
        """Largest |error| of ``output`` ("heading", "pitch", "roll") over the unflagged points."""
        if output not in OUTPUTS:
            raise ShipstarError(f"output must be one of {OUTPUTS}, got {output!r}")
        if kind not in ("rss", "signed_sum"):
            raise ShipstarError(f"kind must be 'rss' or 'signed_sum', got {kind!r}")
        i = OUTPUTS.index(output)
        vals = np.abs(getattr(self.budget, f"{kind}_arcsec")[..., i])
        if np.all(np.isnan(vals)):
            raise ShipstarError(f"every point of the {self.param} sweep is at gimbal lock")
        k, j = np.unravel_index(np.nanargmax(vals), vals.shape)
        return SweepMax(param=self.param, output=output, max_arcsec=float(vals[k, j]),
                        at_deg=float(self.values_deg[j]), curve_label=self.curve_labels[k],
                        ship_pitch_deg=float(self.budget.ship_angles_rad[k, j, 1] * RAD2DEG))

    def rows(self):
        """CSV rows (header first): one per curve and swept value, per-source contributions."""
        head = ["curve", f"{self.param}_deg", "gimbal_locked", "heading_deg", "pitch_deg", "roll_deg"]
        for out in OUTPUTS:
            head += [f"{out}_from_{p}_arcsec" for p in PARAMS]
            head += [f"{out}_rss_arcsec", f"{out}_signed_sum_arcsec"]
        rows = [head]
        b = self.budget
        for k, label in enumerate(self.curve_labels):
            for j, v in enumerate(self.values_deg):
                r = [label, f"{v:.6g}", str(bool(b.gimbal_locked[k, j]))]
                r += [f"{x * RAD2DEG:.6f}" for x in b.ship_angles_rad[k, j]]
                for i in range(3):
                    r += [f"{x:.6g}" for x in b.contributions_arcsec[k, j, i]]
                    r += [f"{b.rss_arcsec[k, j, i]:.6g}", f"{b.signed_sum_arcsec[k, j, i]:.6g}"]
                rows.append(r)
        return rows


def sweep(param: str, errors_arcsec, *, values_deg=None, n_points: int = 361, base_deg=None,
          curve_A0_deg=SEED001_A0_CURVES_DEG, convention: str = "shipstar",
          lock_margin_deg: float = 1.0) -> SweepResult:
    """Sweep one of the six angles, the others fixed, one curve per installation azimuth.

    Parameters
    ----------
    param : str
        One of :data:`PARAMS`.
    errors_arcsec : array_like, shape (6,)
        Errors of (As, Es, gs, A0, E0, g0).
    values_deg : array_like, optional
        Swept values; default ``n_points`` over seed 001's range for ``param``.
    base_deg : dict, optional
        Values of the other angles (default :data:`SEED001_BASE_DEG`).
    curve_A0_deg : sequence of float
        Installation azimuths, one curve each (ignored when ``param == "A0"``).
    convention : {"shipstar", "seed001-factors"}
    lock_margin_deg : float
        Points with ship pitch within this of +-90 deg are flagged and set to NaN.
    """
    if param not in PARAMS:
        raise ShipstarError(f"unknown sweep parameter {param!r}; expected one of {', '.join(PARAMS)}")
    errors = validate_errors_arcsec(errors_arcsec)
    base = dict(SEED001_BASE_DEG if base_deg is None else base_deg)
    if set(base) != set(PARAMS):
        raise ShipstarError(f"base_deg needs exactly the keys {PARAMS}")
    if values_deg is None:
        if int(n_points) < 2:
            raise ShipstarError(f"n_points must be >= 2, got {n_points}")
        values = np.linspace(*SEED001_RANGES_DEG[param], int(n_points))
    else:
        values = np.asarray(values_deg, float).ravel()
        if values.size == 0 or not np.all(np.isfinite(values)):
            raise ShipstarError("sweep values must be finite and non-empty")
    curves = (None,) if param == "A0" else tuple(float(a) for a in curve_A0_deg)
    labels = ("A0 swept",) if param == "A0" else tuple(f"A0 = {a:g} deg" for a in curves)
    grid = np.empty((len(curves), values.size, 6))
    for k, a0 in enumerate(curves):
        for j, p in enumerate(PARAMS):
            grid[k, :, j] = base[p]
        if a0 is not None:
            grid[k, :, 3] = a0
        grid[k, :, PARAMS.index(param)] = values
    grid *= DEG2RAD
    budget = error_budget(grid[..., :3], grid[..., 3:], errors, convention=convention,
                          lock_margin_deg=lock_margin_deg)
    return SweepResult(param=param, values_deg=values, curve_labels=labels, budget=budget,
                       convention=convention, lock_margin_deg=float(lock_margin_deg))


def seed001_sweep(figure: SeedFigure, *, n_points: int = 361, convention: str = "shipstar",
                  lock_margin_deg: float = 1.0) -> SweepResult:
    """The sweep behind one of seed 001's figures (see :data:`SEED001_FIGURES`)."""
    return sweep(figure.param, figure.errors_arcsec, n_points=n_points, convention=convention,
                 lock_margin_deg=lock_margin_deg)


@dataclass(frozen=True)
class SweepMax:
    """Where a sweep's error peaks."""

    param: str
    output: str
    max_arcsec: float
    at_deg: float
    curve_label: str
    ship_pitch_deg: float


@dataclass(frozen=True)
class HeadlineCheck:
    """Seed 001's headline (100'' roll error -> up to 112'' heading error) recomputed.

    Attributes
    ----------
    convention : str
    seed_arcsec : float
        112''.
    max_heading_arcsec : float
        Largest heading error over the sec. 3.1 sweeps (As, Es, gs, A0, E0; roll error
        100'' only), outside the flagged gimbal-lock points.
    at : SweepMax
        Where it occurs.
    per_sweep : tuple of SweepMax
        The heading maximum of each sweep.
    base_point_max_arcsec : float
        Largest heading error at the seed's base point over the four installation azimuths.
    n_gimbal_locked : int
        Points flagged (and left out) in all sweeps together.
    lock_margin_deg : float
    """

    convention: str
    seed_arcsec: float
    max_heading_arcsec: float
    at: SweepMax
    per_sweep: tuple
    base_point_max_arcsec: float
    n_gimbal_locked: int
    lock_margin_deg: float


def seed001_headline(*, convention: str = "shipstar", n_points: int = 361,
                     lock_margin_deg: float = 1.0) -> HeadlineCheck:
    """Recompute seed 001's headline over its sec. 3.1 sweeps."""
    per_sweep = []
    n_locked = 0
    for fig in SEED001_FIGURES:
        if fig.section != "3.1":
            continue
        res = seed001_sweep(fig, n_points=n_points, convention=convention, lock_margin_deg=lock_margin_deg)
        per_sweep.append(res.max_abs("heading"))
        n_locked += res.n_gimbal_locked
    best = max(per_sweep, key=lambda m: m.max_arcsec)
    base = np.array([[SEED001_BASE_DEG[p] if p != "A0" else a0 for p in PARAMS]
                     for a0 in SEED001_A0_CURVES_DEG]) * DEG2RAD
    b = error_budget(base[:, :3], base[:, 3:], SEED001_ROLL_ONLY_ERRORS_ARCSEC, convention=convention,
                     lock_margin_deg=lock_margin_deg)
    return HeadlineCheck(convention=convention, seed_arcsec=SEED001_HEADLINE_ARCSEC,
                         max_heading_arcsec=best.max_arcsec, at=best, per_sweep=tuple(per_sweep),
                         base_point_max_arcsec=float(np.nanmax(np.abs(b.rss_arcsec[:, 0]))),
                         n_gimbal_locked=n_locked, lock_margin_deg=float(lock_margin_deg))
