"""Seed 001's conclusions (sec. 3.1-3.3), each checked against its sweep.

Two models are checked:

``"shipstar"``
    Seed 001 eq. 1-4 as printed, in shipstar's conventions, with independent errors
    combined by root-sum-square (the physically right reading).
``"seed001"``
    What the seed's own factors (eq. 8-38) and figures encode: the installation matrix
    used untransposed (``convention="seed001-factors"``) and the errors added with their
    signs, all positive (eq. 5-7 taken literally).

A trend is read from a curve ``y`` (absolute error, arcsec) with the tolerances below;
they are stated in ``docs/error-model.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.units import DEG2RAD

from ._budget import error_budget
from ._jacobian import OUTPUTS, PARAMS
from ._sweep import (
    SEED001_A0_CURVES_DEG, SEED001_BASE_DEG, SEED001_FIGURES, SEED001_HEADLINE_ARCSEC,
    SEED001_ROLL_ONLY_ERRORS_ARCSEC, SweepResult, seed001_headline, seed001_sweep,
)

__all__ = ["MODELS", "Conclusion", "trend", "check_seed001_conclusions", "conclusions_markdown"]

#: model name -> (convention, how the sources are combined)
MODELS = {"shipstar": ("shipstar", "rss"), "seed001": ("seed001-factors", "signed_sum")}

#: Reading a trend off a figure: a curve whose range is below this fraction of its
#: maximum is "constant"; a monotone trend must move by at least this fraction and never
#: go back by more than it.
TREND_TOL = 0.10
#: trends that count as "oscillating" (the curve turns at least once)
NON_MONOTONE = frozenset({"oscillating", "decreasing-then-increasing", "increasing-then-decreasing"})
#: the headline "holds" within this relative tolerance of 112''
HEADLINE_TOL = 0.05


def _monotone(y, scale, sign):
    y = sign * y
    back = np.max(np.maximum.accumulate(y) - y)
    return (y[-1] - y[0]) >= TREND_TOL * scale and back <= TREND_TOL * scale


def trend(y) -> str:
    """Classify a curve: "constant", "increasing", "decreasing",
    "decreasing-then-increasing", "increasing-then-decreasing" or "oscillating".

    NaN points (gimbal lock) are dropped; the tolerance is :data:`TREND_TOL`.
    """
    y = np.asarray(y, float)
    y = y[np.isfinite(y)]
    if y.size < 3:
        raise ShipstarError("a trend needs at least 3 finite points")
    scale = float(np.max(np.abs(y)))
    if np.ptp(y) <= TREND_TOL * scale + 1e-9:
        return "constant"
    if _monotone(y, scale, +1):
        return "increasing"
    if _monotone(y, scale, -1):
        return "decreasing"
    for name, k, first, second in (("decreasing-then-increasing", int(np.argmin(y)), -1, +1),
                                   ("increasing-then-decreasing", int(np.argmax(y)), +1, -1)):
        if 0 < k < y.size - 1 and _monotone(y[:k + 1], scale, first) and _monotone(y[k:], scale, second):
            return name
    return "oscillating"


@dataclass(frozen=True)
class Conclusion:
    """One of seed 001's conclusions, checked.

    ``key`` is the seed's numbering ("3.2(5)"), ``figure`` the sweep that decides it,
    ``evidence`` a one-line summary of the numbers.
    """

    key: str
    statement: str
    figure: str
    held: bool
    evidence: str


class _Sweeps:
    """Seed figures computed once per model, with |error| curves by output and curve."""

    def __init__(self, model: str, n_points: int):
        self.convention, self.kind = MODELS[model]
        self.results = {f.key: seed001_sweep(f, n_points=n_points, convention=self.convention)
                        for f in SEED001_FIGURES}

    def curve(self, fig: str, output: str, a0=None):
        res: SweepResult = self.results[fig]
        k = 0 if a0 is None else res.curve_labels.index(f"A0 = {a0:g} deg")
        return np.abs(getattr(res.budget, f"{self.kind}_arcsec")[k, :, OUTPUTS.index(output)])

    def trends(self, fig, output, a0=None):
        return trend(self.curve(fig, output, a0))


def _fmt(y):
    y = y[np.isfinite(y)]
    return f"{y[0]:.1f}''->{y[-1]:.1f}'' (range {np.min(y):.1f}-{np.max(y):.1f}'')"


def _c31(s: _Sweeps, n_points: int):
    out = []
    h = seed001_headline(convention=s.convention, n_points=n_points)
    peak = h.at
    out.append(Conclusion(
        "3.1(1)", "a 100'' sensor roll error gives up to 112'' of heading error", "fig1-3 (+ gs, A0)",
        abs(h.max_heading_arcsec / SEED001_HEADLINE_ARCSEC - 1) <= HEADLINE_TOL,
        f"max over the sec. 3.1 sweeps {h.max_heading_arcsec:.1f}'' ({peak.param} = {peak.at_deg:g} deg, "
        f"{peak.curve_label}, ship pitch {peak.ship_pitch_deg:.1f} deg); per sweep: "
        + ", ".join(f"{m.param} {m.max_arcsec:.1f}''" for m in h.per_sweep)))
    flat = [s.trends("fig1_As", o, a) for o in OUTPUTS for a in SEED001_A0_CURVES_DEG]
    out.append(Conclusion("3.1(2)", "the ship attitude error does not vary with As", "fig1_As",
                          all(t == "constant" for t in flat), f"trends: {sorted(set(flat))}"))
    osc = {}
    for fig in ("fig2_Es", "fig2_gs", "fig2_A0"):
        a0s = (None,) if fig == "fig2_A0" else SEED001_A0_CURVES_DEG
        osc[fig] = sorted({s.trends(fig, o, a) for o in OUTPUTS for a in a0s})
    out.append(Conclusion("3.1(3)", "the error oscillates with Es, gs and A0", "fig2_Es (+ gs, A0)",
                          all(NON_MONOTONE & set(v) for v in osc.values()),
                          "; ".join(f"{s.results[k].param}: {v}" for k, v in osc.items())))
    out += _c31_layout(s)
    return out


def _base_roll_only(s: _Sweeps, a0):
    x = np.array([SEED001_BASE_DEG[p] if p != "A0" else a0 for p in PARAMS]) * DEG2RAD
    b = error_budget(x[:3], x[3:], SEED001_ROLL_ONLY_ERRORS_ARCSEC, convention=s.convention)
    return np.abs(b.contributions_arcsec[:, 2])


def _c31_layout(s: _Sweeps):
    out = []
    along = [_base_roll_only(s, a) for a in (0.0, 180.0)]
    across = [_base_roll_only(s, a) for a in (90.0, 270.0)]
    ev = "base point (E0 = 35 deg), |d(K, psi, theta)| from 100'' roll: " + ", ".join(
        f"A0={a:g}: ({v[0]:.1f}, {v[1]:.1f}, {v[2]:.1f})''" for a, v in zip((0, 180, 90, 270), along + across))
    out.append(Conclusion("3.1(4a)", "A0 = 0/180 deg: the roll error acts mainly on ship roll", "fig3_E0",
                          all(int(np.argmax(v)) == 2 for v in along), ev))
    out.append(Conclusion("3.1(4b)", "A0 = 90/270 deg: the roll error acts mainly on heading", "fig3_E0",
                          all(int(np.argmax(v)) == 0 for v in across), ev))
    t = {(o, a): s.trends("fig3_E0", o, a) for o in OUTPUTS for a in SEED001_A0_CURVES_DEG}
    ok = all(t[(o, a)] == "increasing" for o in ("heading", "pitch") for a in (0.0, 180.0))
    out.append(Conclusion("3.1(4c)", "A0 = 0/180 deg: heading and pitch errors increase with E0", "fig3_E0", ok,
                          _trend_ev(s, "fig3_E0", (("heading", 0.0), ("pitch", 0.0), ("heading", 180.0)))))
    ok = (all(t[("pitch", a)] == "increasing" for a in (90.0, 270.0))
          and all(t[(o, a)] == "decreasing" for o in ("heading", "roll") for a in (90.0, 270.0)))
    out.append(Conclusion("3.1(4d)", "A0 = 90/270 deg: pitch error increases with E0, roll and heading decrease",
                          "fig3_E0", ok,
                          _trend_ev(s, "fig3_E0", (("pitch", 90.0), ("roll", 90.0), ("heading", 270.0)))))
    return out


def _trend_ev(s, fig, pairs):
    return "; ".join(f"{o} A0={a:g}: {s.trends(fig, o, a)} {_fmt(s.curve(fig, o, a))}" for o, a in pairs)


def _c32(s: _Sweeps):
    out = []
    t4 = sorted({s.trends("fig4_A0", o) for o in OUTPUTS})
    out.append(Conclusion("3.2(1)", "the error oscillates with A0", "fig4_A0",
                          bool(NON_MONOTONE & set(t4)), f"trends: {t4}"))
    t5 = {(o, a): s.trends("fig5_g0", o, a) for o in OUTPUTS for a in SEED001_A0_CURVES_DEG}
    out.append(Conclusion("3.2(2)", "the error does not vary with g0", "fig5_g0",
                          all(v == "constant" for v in t5.values()),
                          _trend_ev(s, "fig5_g0", (("heading", 0.0), ("roll", 0.0), ("roll", 90.0)))))
    tp = [s.trends("fig6_E0", "pitch", a) for a in SEED001_A0_CURVES_DEG]
    out.append(Conclusion("3.2(3)", "the pitch error increases with E0", "fig6_E0",
                          all(v == "increasing" for v in tp),
                          _trend_ev(s, "fig6_E0", tuple(("pitch", a) for a in SEED001_A0_CURVES_DEG))))
    claims = (("3.2(4)", 0.0, "increasing", "decreasing", "heading error increases, roll error decreases"),
              ("3.2(5)", 90.0, "decreasing", "decreasing", "heading and roll errors decrease"),
              ("3.2(6)", 180.0, "increasing", "decreasing-then-increasing",
               "heading error increases, roll error first decreases then increases"),
              ("3.2(7)", 270.0, "decreasing", "decreasing-then-increasing",
               "heading error decreases, roll error first decreases then increases"))
    for key, a0, th, tr, text in claims:
        ok = s.trends("fig6_E0", "heading", a0) == th and s.trends("fig6_E0", "roll", a0) == tr
        out.append(Conclusion(key, f"A0 = {a0:g} deg: with E0, {text}", "fig6_E0", ok,
                              _trend_ev(s, "fig6_E0", (("heading", a0), ("roll", a0)))))
    return out


def _factor_check(s: _Sweeps, column: int, target: int):
    """Max deviation of Jacobian column from the unit vector e_target over all sweeps."""
    dev = 0.0
    for res in s.results.values():
        J = res.budget.jacobian[..., :, column]
        e = np.zeros(3)
        e[target] = 1.0
        dev = max(dev, float(np.nanmax(np.abs(J - e))))
    return dev


def _c33(s: _Sweeps, c31, c32):
    out = []
    d = _factor_check(s, PARAMS.index("As"), 0)
    out.append(Conclusion("3.3(1)", "dAs acts only on heading, with factor 1, whatever As", "all",
                          d < 1e-9, f"max |dK,dpsi,dtheta / dAs - (1, 0, 0)| over all sweeps = {d:.2e}"))
    d = _factor_check(s, PARAMS.index("g0"), 2)
    out.append(Conclusion("3.3(2)", "dg0 acts only on roll, with factor 1, whatever g0", "fig5_g0",
                          d < 1e-9, f"max |dK,dpsi,dtheta / dg0 - (0, 0, 1)| over all sweeps = {d:.3g}"))
    a, b = (next(c for c in c31 if c.key == k) for k in ("3.1(4a)", "3.1(4b)"))
    out.append(Conclusion("3.3(3)", "the roll error acts mainly on roll along the fore-aft line, "
                          "mainly on heading across it", "fig3_E0", a.held and b.held, a.evidence))
    p = next(c for c in c32 if c.key == "3.2(3)")
    out.append(Conclusion("3.3(4)", "the pitch error increases with E0", "fig6_E0", p.held, p.evidence))
    return out


def check_seed001_conclusions(model: str = "shipstar", *, n_points: int = 361) -> tuple:
    """Every conclusion of seed 001 sec. 3.1-3.3, checked on its sweep.

    Parameters
    ----------
    model : {"shipstar", "seed001"}
        See the module docstring.
    n_points : int
        Points per sweep.

    Returns
    -------
    tuple of Conclusion
    """
    if model not in MODELS:
        raise ShipstarError(f"unknown model {model!r}; expected one of {', '.join(MODELS)}")
    s = _Sweeps(model, n_points)
    c31 = _c31(s, n_points)
    c32 = _c32(s)
    return tuple(c31 + c32 + _c33(s, c31, c32))


def conclusions_markdown(*, n_points: int = 361) -> str:
    """The verdict table of ``docs/error-model.md`` (both models side by side)."""
    ship = check_seed001_conclusions("shipstar", n_points=n_points)
    seed = check_seed001_conclusions("seed001", n_points=n_points)
    lines = ["| seed 001 | statement | figure | shipstar model (eq. 1-4, RSS) | seed's own model |",
             "|---|---|---|---|---|"]
    for a, b in zip(ship, seed):
        lines.append(f"| {a.key} | {a.statement} | {a.figure} | {'held' if a.held else '**not held**'} "
                     f"| {'held' if b.held else 'not held'} |")
    return "\n".join(lines) + "\n"
