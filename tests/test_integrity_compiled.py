"""pipeline._integrity.check_integrity compiled (attitude._ckernels.integrity) against its
NumPy path: the same decisions (checked, consistent, suspect) and numbers to rounding."""

from __future__ import annotations

import numpy as np
import pytest

import shipstar.pipeline._integrity as integrity
from shipstar.pipeline._motion import expm_rotvec
from shipstar.units import ASEC2RAD


def _case(rng, n, spread_arcsec):
    C0 = expm_rotvec(rng.normal(size=3))
    Cs = [C0 @ expm_rotvec(rng.normal(scale=spread_arcsec * ASEC2RAD, size=3)) for _ in range(n)]
    Ps = []
    for _ in range(n):
        A = rng.normal(scale=3.0 * ASEC2RAD, size=(3, 3))
        Ps.append(A @ A.T + (0.1 * ASEC2RAD) ** 2 * np.eye(3))
    return [f"S{k}" for k in range(n)], Cs, Ps, list(rng.uniform(0.5, 3.0, size=n))


def _both(monkeypatch, *args):
    monkeypatch.setattr(integrity, "_COMPILED", [True])
    a = integrity.check_integrity(*args)
    monkeypatch.setattr(integrity, "_COMPILED", [False])
    return a, integrity.check_integrity(*args)


@pytest.mark.parametrize("n", [2, 3, 4])
def test_compiled_and_numpy_paths_agree(n, monkeypatch):
    rng = np.random.default_rng(n)
    n_inconsistent = 0
    for trial in range(60):
        spread = 30.0 if trial % 3 == 0 else 2.0           # every third case far beyond the sigmas
        a, b = _both(monkeypatch, *_case(rng, n, spread))
        assert (a.checked, a.consistent, a.suspect, a.dof) == (b.checked, b.consistent, b.suspect, b.dof)
        assert a.chi2 == pytest.approx(b.chi2, rel=1e-9)
        assert a.limit == b.limit
        assert a.disagreement_arcsec == pytest.approx(b.disagreement_arcsec, rel=1e-9)
        n_inconsistent += not a.consistent
    assert 10 <= n_inconsistent <= 50


def test_a_covariance_not_finite_is_not_checked_on_either_path(monkeypatch):
    names, Cs, Ps, sig = _case(np.random.default_rng(7), 2, 2.0)
    Ps[1] = Ps[1].copy()
    Ps[1][0, 0] = np.nan
    a, b = _both(monkeypatch, names, Cs, Ps, sig)
    assert not a.checked and not b.checked
