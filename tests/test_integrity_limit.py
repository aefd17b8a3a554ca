"""pipeline._integrity's chi-square quantile (closed form for integer dof) against scipy's
``chdtri`` / ``chdtrc`` (cephes), the reference it replaced at run time."""

from __future__ import annotations

import pytest
from scipy.special import chdtrc, chdtri

from shipstar.pipeline._integrity import (
    FALSE_ALARM_PROBABILITY,
    chi2_isf_int,
    chi2_limit,
    chi2_sf_int,
)


@pytest.mark.parametrize("dof", list(range(1, 13)) + [15, 30, 40])
@pytest.mark.parametrize("p", [1e-12, 1e-6, 1e-3, 1e-2, 0.05, 0.5, 0.99])
def test_quantile_and_survival_agree_with_scipy_to_machine_precision(dof, p):
    ref = float(chdtri(dof, p))
    assert chi2_isf_int(dof, p) == pytest.approx(ref, rel=1e-13, abs=0.0)
    assert chi2_sf_int(ref, dof) == pytest.approx(float(chdtrc(dof, ref)), rel=1e-12, abs=0.0)


def test_the_engine_limits_are_the_documented_ones():
    # two sensors: 3 dof at one false alarm in a million (module docstring: 30.66)
    assert chi2_limit(3) == pytest.approx(30.664849706213598, rel=1e-15)
    assert chi2_limit(3, FALSE_ALARM_PROBABILITY) == chi2_limit(3)
    assert chi2_sf_int(chi2_limit(6), 6) == pytest.approx(FALSE_ALARM_PROBABILITY, rel=1e-13)
