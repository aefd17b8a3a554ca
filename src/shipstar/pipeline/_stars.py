"""Catalog lookup of identified stars: HIP numbers -> unrefracted apparent horizontal directions."""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["StarLookup", "default_lookup"]


class StarLookup:
    """HIP -> ERFA star arguments, computed once for a whole catalog.

    ``FrameContext.hor_from_catalog`` recomputes the ERFA arguments of the catalog it is
    given on every call (2.5 ms for all of Hipparcos); this keeps them, so one frame's
    20-100 stars cost ~40 us.

    Parameters
    ----------
    catalog : shipstar.sky.catalog.StarCatalog
    """

    def __init__(self, catalog):
        self.catalog = catalog
        self._args = tuple(np.asarray(a) for a in catalog.erfa_args())

    def hor(self, context, hip) -> np.ndarray:
        """Apparent horizontal directions ``(N, 3)`` (no refraction) of HIP numbers ``(N,)``.

        Raises
        ------
        ShipstarError
            An unknown HIP number.
        """
        rows = self.catalog.index_of_hip(np.asarray(hip, np.int64))
        return context.hor_from_star_args(*(a[rows] for a in self._args))


@functools.lru_cache(maxsize=1)
def default_lookup() -> StarLookup:
    """Lookup over the full Hipparcos catalog (loaded once, disk-cached by ``sky.catalog``)."""
    from shipstar.sky.catalog import load_hipparcos

    return StarLookup(load_hipparcos())
