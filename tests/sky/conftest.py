"""Shared set-up for tests/sky: astropy (a test-only reference) works offline.

astropy's Earth orientation must never download and never refuse: tests run with the
network off, and astropy's IERS_Auto refuses predicted values more than 30 days old
(which, with the shipped astropy-iers-data, starts on 2026-11-22) unless
``auto_max_age = None``.  Every test here also uses astropy's *bundled* IERS-A table
explicitly (:func:`astropy_iers_a`), the same ``finals2000A.all`` shipstar reads, so both
sides use the same Earth orientation.

pytest turns warnings into errors.  The only astropy/ERFA warnings filtered are the ones
a comparison past the end of the IERS table must produce, and only inside
:func:`past_iers_table_end`:

- ``IERSDegradedAccuracyWarning`` (astropy holds the table's last UT1-UTC);
- astropy's ``"Tried to get polar motions for times after IERS data is valid"``
  (astropy then uses its 50-year mean polar motion);
- ERFA's ``"dubious year"`` notice (ERFA 2.0.1 flags every year from 2029 on).
"""

from __future__ import annotations

import contextlib
import warnings

import pytest


@pytest.fixture(scope="session", autouse=True)
def _astropy_offline():
    """Configure astropy's IERS handling for the whole session (no download, no refusal)."""
    from astropy.utils import iers

    with iers.conf.set_temp("auto_download", False), \
            iers.conf.set_temp("auto_max_age", None), \
            iers.conf.set_temp("iers_degraded_accuracy", "warn"):
        yield


@pytest.fixture(scope="session")
def astropy_iers_a(_astropy_offline):
    """astropy's bundled IERS-A table (astropy-iers-data's finals2000A.all), in force."""
    from astropy.utils import iers

    table = iers.IERS_A.open(iers.IERS_A_FILE)
    with iers.earth_orientation_table.set(table):
        yield table


@pytest.fixture
def past_iers_table_end():
    """Context manager muting exactly the warnings astropy gives past the IERS table."""

    @contextlib.contextmanager
    def ctx():
        import erfa
        from astropy.utils.exceptions import AstropyWarning
        from astropy.utils.iers import IERSDegradedAccuracyWarning

        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", category=IERSDegradedAccuracyWarning)
            warnings.filterwarnings("ignore", message="Tried to get polar motions for times after",
                                    category=AstropyWarning)
            warnings.filterwarnings("ignore", message=r".*dubious year", category=erfa.ErfaWarning)
            yield

    return ctx
