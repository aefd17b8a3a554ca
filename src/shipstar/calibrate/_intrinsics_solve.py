"""The estimation strategies: seed 002's two-step iteration and the joint fit.

Both start from the input (nominal) camera with its distortion set to zero.

**Gauge.**  Interstar angles are blind to a rotation of the sensor, and to first order in
the field angle a shift of the principal point *is* a rotation plus a quadratic image
distortion, which the decentring and thin-prism terms (p1, p2, s1, s2) reproduce
exactly.  The cost therefore has a long, curved valley in (x0, y0, p, s), and for a lens
with strong quadratic terms (seed 002 Tab. 1 read in mm) a second, equally good minimum
far from the first.  Both strategies pick the solution reached continuously from the
*nominal* principal point: the first, distortion-free step fits the focal length only
(seed 002 fits f and the principal point there; with Tab. 1's lens that sends the
principal point ~1300 px away, toward the other minimum), and the principal point is
released once the distortion can absorb what belongs to it.

**Two-step (seed 002 sec. 2).**  Step 1: distortion zero, least squares for f (only the
stars near the centre of the field first, as the seed does, then all).  Step 2: the
distortion terms with f and the principal point fixed.  Step 3: f and the principal
point with the distortion fixed.  Steps 2-3 repeat until no parameter moves an edge
star by more than ``tol_px``.  Alternating least squares crawls along the valley (about
1.6 % per cycle for the Tab. 1 lens), so every cycle whose step is nearly parallel to the
previous one is extrapolated (Aitken's delta-squared on the step lengths) and the jump is
kept if it lowers the cost; once a cycle moves no parameter by more than ``tol_px``, one
Gauss-Newton solve over all parameters of the same equations finishes the approach.  The
fixed point is unchanged: the least-squares solution of the chosen equations.

**Joint.**  All free parameters (and, with ``attitudes``, a rotation per frame) by
Levenberg-Marquardt with a Huber loss: first with the principal point held, then with
everything free.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shipstar.calibrate._intrinsics_lsq import Fit, levenberg_marquardt
from shipstar.calibrate._intrinsics_model import PARAM_NAMES, ParamSpace, sensor_vectors
from shipstar.calibrate._intrinsics_pairs import StarSet, evaluate
from shipstar.camera import Camera, Distortion

__all__ = ["SolveOutcome", "two_step", "joint", "central_stars", "initial_attitudes"]

PP = ("x0_px", "y0_px")
FP = ("f_mm",) + PP
#: fraction of the half-diagonal that counts as "the centre of the field" for step 1
CENTRAL_FRACTION = 0.5
#: Aitken jumps are taken when consecutive steps agree in direction to this cosine
_PARALLEL_COS = 0.95
_MAX_JUMP = 1000.0
#: the steps inside a cycle need not converge further than the cycle's own tolerance
_INNER_TOL_PX = 1e-4


@dataclass(frozen=True)
class SolveOutcome:
    """What a strategy reached: the camera, its effort, and (joint) the last fit."""

    camera: Camera
    iterations: int
    converged: bool
    fit: Fit | None                    # final joint fit (joint strategy) or None
    attitudes: np.ndarray | None       # (F, 3, 3) C_ref_from_sensor (joint on stars)


def central_stars(stars: StarSet, camera: Camera, fraction: float = CENTRAL_FRACTION):
    """The stars within ``fraction`` of the half-diagonal from the image centre (stars
    left with fewer than 3 stars are dropped)."""
    c = np.array([(camera.width_px - 1) / 2.0, (camera.height_px - 1) / 2.0])
    radius = fraction * float(np.hypot(*c))
    return stars.subset(np.hypot(*(stars.xy_px - c).T) < radius)


def _fit_subset(stars, camera: Camera, free, kind, **kw) -> tuple[Camera, Fit]:
    space = ParamSpace.for_camera(camera, free)
    fit = levenberg_marquardt(stars, space, space.values(camera), kind, **kw)
    return space.camera(fit.theta), fit


def pair_cost(stars: StarSet, camera: Camera, kind: str) -> float:
    full = ParamSpace.for_camera(camera, ()).full(())
    r = evaluate(stars, full, camera.pixel_mm, (), kind).r
    return float(r @ r)


def _step1(stars, start: Camera, kind: str) -> Camera:
    """Distortion zero, focal length only: central stars first, then all."""
    cam = start.replace(distortion=Distortion())
    centre = central_stars(stars, cam)
    if centre.n_pairs >= 10:
        cam, _ = _fit_subset(centre, cam, ("f_mm",), kind)
    cam, _ = _fit_subset(stars, cam, ("f_mm",), kind)
    return cam


def two_step(stars, start: Camera, kind: str, terms, *, max_cycles: int = 300,
             tol_px: float = 1e-3) -> SolveOutcome:
    """Seed 002's iteration on the ``kind`` ("sine" or "cosine") equations.

    ``terms`` are Distortion field names to estimate (empty: the plain method of the
    seed's ref. [11], f and principal point only).
    """
    cam = _step1(stars, start, kind)
    if not terms:
        cam, fit = _fit_subset(stars, cam, FP, kind)
        return SolveOutcome(cam, 1, fit.converged, None, None)
    everything = ParamSpace.for_camera(cam, all_free(terms))
    scales = everything.scales
    prev_step = None
    converged = False
    cycle = 0
    for cycle in range(1, max_cycles + 1):
        before = everything.values(cam)
        cam, _ = _fit_subset(stars, cam, tuple(terms), kind, tol_px=_INNER_TOL_PX)   # step 2
        cam, _ = _fit_subset(stars, cam, FP, kind, tol_px=_INNER_TOL_PX)             # step 3
        step = (everything.values(cam) - before) / scales
        size = float(np.max(np.abs(step)))
        if size < tol_px:
            converged = True
            break
        cam = _aitken(stars, cam, everything, step, prev_step, kind)
        prev_step = step
    if converged:
        # Near the end alternation contracts by ~2 % per cycle, so a 1e-3 px step still
        # leaves ~0.05 px to go; one joint Gauss-Newton on the same equations lands on
        # the same fixed point (the least-squares solution).
        cam, fit = _fit_subset(stars, cam, all_free(terms), kind)
        converged = fit.converged
    return SolveOutcome(cam, cycle, converged, None, None)


def _aitken(stars, cam, space, step, prev_step, kind):
    """Extrapolate a geometric sequence of steps; keep the jump only if it helps."""
    if prev_step is None:
        return cam
    n1, n0 = np.linalg.norm(step), np.linalg.norm(prev_step)
    if n0 == 0.0 or n1 >= n0 or float(step @ prev_step) < _PARALLEL_COS * n1 * n0:
        return cam
    ratio = n1 / n0
    factor = min(ratio / (1.0 - ratio), _MAX_JUMP)
    theta = space.values(cam) + factor * step * space.scales
    try:
        trial = space.with_base(cam).camera(theta)
    except ValueError:                       # a distortion the camera cannot invert
        return cam
    if pair_cost(stars, trial, kind) < pair_cost(stars, cam, kind):
        return trial
    return cam


def initial_attitudes(stars, camera: Camera):
    """QUEST attitude ``C_ref_from_sensor`` of every frame with ``camera``."""
    from shipstar.attitude import quest

    full = ParamSpace.for_camera(camera, ()).full(())
    w = sensor_vectors(stars.xy_px, full, camera.pixel_mm, ())[0]
    out = []
    for s, n in zip(stars.starts, stars.counts):
        out.append(np.asarray(quest(w[s:s + n], stars.v_ref[s:s + n]), float))
    return np.array(out)


def joint(stars, start: Camera, terms, *, attitudes: bool = True, robust: bool = True,
          max_iter: int = 100) -> SolveOutcome:
    """All parameters at once (Levenberg-Marquardt, Huber loss), principal point held
    in a first pass."""
    kind = "star" if attitudes else "angle"
    cam = _step1(stars, start, "angle")
    held = ("f_mm",) + tuple(terms)
    kw = dict(robust=robust, max_iter=max_iter)
    att = initial_attitudes(stars, cam) if attitudes else None
    space = ParamSpace.for_camera(cam, held)
    fit = levenberg_marquardt(stars, space, space.values(cam), kind, attitudes0=att, **kw)
    cam = space.camera(fit.theta)
    n_iter = fit.iterations
    space = ParamSpace.for_camera(cam, all_free(terms))
    fit = levenberg_marquardt(stars, space, space.values(cam), kind, attitudes0=fit.attitudes, **kw)
    return SolveOutcome(space.camera(fit.theta), n_iter + fit.iterations, fit.converged, fit,
                        fit.attitudes)


def all_free(terms) -> tuple:
    """Parameter names estimated with these distortion terms, in PARAM_NAMES order."""
    chosen = set(FP) | set(terms)
    return tuple(n for n in PARAM_NAMES if n in chosen)
