"""solve_attitude's compiled QUEST path (``attitude._ckernels``) against its Python path.

The Python path is the reference (its own tests check it against analytic cases and the
Cramer-Rao bound); the compiled one must give the same solution to rounding on every
kind of input the pipeline gives it (weights or sigma, information matrices or not, an
absolute limit, outliers to reject, few vectors), and hand every failure to the Python
path so that the reason is the same word for word.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from shipstar.attitude import _solve, solve_attitude
from shipstar.frames import C_icrs_from_sensor
from shipstar.units import ASEC2RAD


@pytest.fixture
def python_path():
    """Run solve_attitude by its Python path inside the block."""
    def run(*args, **kwargs):
        _solve._COMPILED[0] = False
        try:
            return solve_attitude(*args, **kwargs)
        finally:
            _solve._COMPILED[0] = True
    return run


def _case(rng, n, *, outliers=0, sigma_arcsec=2.0, field_deg=12.0):
    C = C_icrs_from_sensor(*rng.uniform(0, 2 * math.pi, 3))
    half = math.radians(field_deg / 2)
    w = np.column_stack([rng.uniform(-half, half, (n, 2)), np.ones(n)])
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    v = w @ C.T
    noise = rng.normal(scale=sigma_arcsec * ASEC2RAD, size=(n, 3))
    w_meas = w + noise - (noise * w).sum(axis=1, keepdims=True) * w
    kick = np.cross(w[:outliers], rng.normal(size=(outliers, 3)))      # 200'' across the line of sight
    w_meas[:outliers] += 200 * ASEC2RAD * kick / np.linalg.norm(kick, axis=1, keepdims=True)
    # anisotropic information: a streak along a random direction across each star
    along = np.cross(w, rng.normal(size=3))
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    across = np.cross(w, along)
    info = (np.einsum("ni,nj->nij", across, across) / (sigma_arcsec * ASEC2RAD) ** 2
            + np.einsum("ni,nj->nij", along, along) / (3 * sigma_arcsec * ASEC2RAD) ** 2)
    return w_meas * rng.uniform(0.5, 2.0, (n, 1)), v, info       # rows not unit: normalised inside


def _same(a, b):
    assert a.solved and b.solved
    assert a.reason == b.reason == ""
    np.testing.assert_array_equal(a.inliers, b.inliers)
    assert a.n_used == b.n_used
    np.testing.assert_allclose(a.C_ref_from_body, b.C_ref_from_body, rtol=0, atol=1e-12)   # 2e-7 arcsec
    np.testing.assert_allclose(a.q_wxyz, b.q_wxyz, rtol=0, atol=1e-12)   # 2e-7 arcsec
    scale = np.abs(b.covariance_rad2).max()
    np.testing.assert_allclose(a.covariance_rad2, b.covariance_rad2, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(a.residuals_arcsec, b.residuals_arcsec, rtol=0, atol=1e-6)
    np.testing.assert_allclose(a.sigma_rad, b.sigma_rad, rtol=1e-9)
    assert a.rms_arcsec == pytest.approx(b.rms_arcsec, rel=1e-9)
    if b.info_per_rad2 is None:
        assert a.info_per_rad2 is None
    else:
        np.testing.assert_allclose(a.info_per_rad2, b.info_per_rad2, rtol=1e-9)


@pytest.mark.parametrize("n, outliers", [(3, 0), (5, 1), (25, 0), (60, 4)])
@pytest.mark.parametrize("mode", ["weights+info", "weights", "sigma+info", "sigma", "limit", "no-reject"])
def test_compiled_path_gives_the_python_solution(python_path, n, outliers, mode):
    rng = np.random.default_rng(1000 * n + len(mode))
    for _ in range(10):
        w, v, info = _case(rng, n, outliers=outliers)
        kwargs = {}
        if "weights" in mode:
            kwargs["weights"] = rng.uniform(0.2, 1.0, n)
        if "sigma" in mode:
            kwargs["sigma_rad"] = rng.uniform(1.0, 3.0, n) * ASEC2RAD
        if "info" in mode:
            kwargs["info_per_rad2"] = info
        if mode == "limit":
            kwargs["max_residual_arcsec"] = 30.0
        if mode == "no-reject":
            kwargs["reject_outliers"] = False
        b = python_path(w, v, **kwargs)
        if not b.solved:                       # e.g. two of three vectors out: a failure either way
            a = solve_attitude(w, v, **kwargs)
            assert (a.solved, a.reason) == (False, b.reason)
            continue
        _same(solve_attitude(w, v, **kwargs), b)
        if outliers and mode != "no-reject" and n > 5:
            assert not b.inliers[:outliers].any()      # the case does test the rejection


def test_compiled_path_runs_and_is_faster_than_nothing_to_check(python_path):
    """The compiled kernel is the one that answers (not a silent fall-back every time)."""
    from shipstar.attitude import _ckernels

    rng = np.random.default_rng(7)
    w, v, info = _case(rng, 20)
    n = len(w)
    out = [np.empty((n, 3)), np.empty((n, 3)), np.empty((3, 3)), np.empty(n), np.empty(n, np.uint8),
           np.empty((3, 3)), np.empty((n, 3, 3)), np.empty(n), np.empty(n)]
    status, scale, rms_rad = _ckernels.solve(np.ascontiguousarray(w), v, np.ones(n), np.empty(0),
                                             np.ascontiguousarray(info), np.array([5.0, 0.0]),
                                             np.array([2, 1], dtype=np.int64), *out)
    assert status == 0 and scale > 0
    b = python_path(w, v, info_per_rad2=info)
    np.testing.assert_allclose(out[2], b.C_ref_from_body, rtol=0, atol=1e-12)   # 2e-7 arcsec
    assert rms_rad / ASEC2RAD == pytest.approx(b.rms_arcsec, rel=1e-9)


def test_failures_are_worded_by_the_python_path(python_path):
    rng = np.random.default_rng(3)
    w, v, info = _case(rng, 8)
    parallel = np.tile(w[:1], (5, 1)), np.tile(v[:1], (5, 1))
    nan_row = w.copy()
    nan_row[2, 0] = np.nan
    zero_row = v.copy()
    zero_row[1] = 0.0
    two_disagree = w[:2].copy(), v[:2].copy()
    two_disagree[0][1] += 1e-3
    singular_info = np.zeros_like(info)               # no information about any axis: scalar solution
    cases = [
        (parallel, {}),
        ((nan_row, v), {}),
        ((w, zero_row), {}),
        (two_disagree, {"sigma_rad": 1 * ASEC2RAD}),
        ((w, v), {"weights": np.r_[1.0, np.zeros(7)]}),          # one usable vector
        ((w, v), {"info_per_rad2": singular_info}),
    ]
    for (ww, vv), kwargs in cases:
        a, b = solve_attitude(ww, vv, **kwargs), python_path(ww, vv, **kwargs)
        assert (a.solved, a.reason) == (b.solved, b.reason)
        if b.solved:
            _same(a, b)
    with pytest.raises(Exception, match="info_per_rad2 must be"):
        bad = info.copy()
        bad[0, 0, 0] = np.inf
        solve_attitude(w, v, info_per_rad2=bad)


def test_the_kernels_constants_are_the_python_ones():
    """The C file restates _solve.py's thresholds; a change to one must reach the other."""
    from pathlib import Path

    src = (Path(_solve.__file__).parent / "_ckernels.c").read_text()
    defined = dict(re.findall(r"#define (\w+) (\S+)", src))
    assert float(defined["PARALLEL_TOL_RAD"]) == _solve.PARALLEL_TOL_RAD
    assert int(defined["ROBUST_MIN_VECTORS"]) == _solve.ROBUST_MIN_VECTORS
    assert _solve.ROBUST_SIGMA_FLOOR_RAD == pytest.approx(1e-3 * math.pi / (180 * 3600), rel=1e-15)
    assert "1e-3 * (M_PI / (180.0 * 3600.0))" in src
