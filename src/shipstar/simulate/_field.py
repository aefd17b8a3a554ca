"""Which catalog stars can fall in a sensor's field: a KD-tree on J2000 unit vectors.

The tree is built once per catalog (navigation catalog of a magnitude limit, or a
catalog the caller passes) and kept in a small in-memory cache.  A query returns every
star within an angular radius of a direction, widened by the largest proper motion of
the catalog over the years since J2000.0, so that no star that has moved into the field
is missed; the exact per-star transform is then done on those stars only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.frames import unit_from_ra_dec
from shipstar.sky.catalog import StarCatalog, navigation_catalog
from shipstar.units import MAS2RAD

__all__ = ["StarField", "star_field", "field_radius_rad", "MAG_LIMIT_RANGE"]

#: Accepted magnitude limits (Hipparcos Hp); the catalog is incomplete beyond ~9.
MAG_LIMIT_RANGE = (-2.0, 14.0)
#: Catalog J2000.0 epoch (Julian year).
_J2000_JYEAR = 2000.0
_CACHE_MAX = 4
_CACHE: dict = {}


@dataclass(frozen=True, eq=False)
class StarField:
    """A star catalog with a KD-tree on its J2000.0 unit vectors.

    Attributes
    ----------
    catalog : StarCatalog
    tree : scipy.spatial.cKDTree
        Over ``unit_from_ra_dec(catalog.ra_rad, catalog.dec_rad)``, shape (N, 3).
    max_pm_rad_per_yr : float
        Largest total proper motion in the catalog.
    """

    catalog: StarCatalog
    tree: object
    max_pm_rad_per_yr: float

    def near(self, u_center, radius_rad: float, epoch_jyear: float) -> np.ndarray:
        """Indices ``(M,)`` (ascending) of stars within ``radius_rad`` of ``u_center`` (3,)
        at ``epoch_jyear``, plus the proper-motion allowance since J2000.0."""
        radius = radius_rad + self.max_pm_rad_per_yr * abs(epoch_jyear - _J2000_JYEAR)
        chord = 2.0 * math.sin(0.5 * min(radius, math.pi))
        idx = self.tree.query_ball_point(np.asarray(u_center, float), chord + 1e-12)
        return np.sort(np.asarray(idx, dtype=np.intp))


def _build(catalog: StarCatalog) -> StarField:
    from scipy.spatial import cKDTree

    unit = unit_from_ra_dec(catalog.ra_rad, catalog.dec_rad)
    pm = np.hypot(catalog.pm_ra_cosdec_mas_per_yr, catalog.pm_dec_mas_per_yr)
    max_pm = float(np.max(pm, initial=0.0)) * MAS2RAD
    return StarField(catalog=catalog, tree=cKDTree(unit), max_pm_rad_per_yr=max_pm)


def _check_mag_limit(mag_limit) -> float:
    try:
        value = float(mag_limit)
    except (TypeError, ValueError):
        raise ShipstarError(f"mag_limit must be a number, got {mag_limit!r}") from None
    lo, hi = MAG_LIMIT_RANGE
    if not (math.isfinite(value) and lo <= value <= hi):
        raise ShipstarError(f"mag_limit = {mag_limit!r} is outside [{lo:g}, {hi:g}]")
    return value


def star_field(mag_limit=None, catalog: StarCatalog | None = None) -> StarField:
    """The (cached) :class:`StarField` of a magnitude limit and/or a catalog.

    Parameters
    ----------
    mag_limit : float, optional
        Faintest Hipparcos Hp magnitude.  Without ``catalog``: the navigation catalog
        of this limit with no close-pair rule (every star is rendered, doubles too).
        With ``catalog``: that catalog's stars at most this bright.
    catalog : StarCatalog, optional
        Stars to use instead of the navigation catalog.

    Raises
    ------
    ShipstarError
        Neither given, a bad magnitude limit, or ``catalog`` not a StarCatalog.
    """
    limit = None if mag_limit is None else _check_mag_limit(mag_limit)
    if catalog is None:
        if limit is None:
            raise ShipstarError("give a mag_limit or a catalog to simulate stars from")
        key = ("nav", limit)
    else:
        if not isinstance(catalog, StarCatalog):
            raise ShipstarError(f"catalog must be a shipstar.sky.catalog.StarCatalog, got {type(catalog).__name__}")
        key = ("given", id(catalog), limit)
    hit = _CACHE.get(key)
    if hit is not None and (catalog is None or hit[0] is catalog):
        return hit[1]
    if catalog is None:
        source = navigation_catalog(limit, 0.0)
    else:
        source = catalog if limit is None else catalog.subset(catalog.mag <= limit)
    field = _build(source)
    if len(_CACHE) >= _CACHE_MAX:
        _CACHE.pop(next(iter(_CACHE)))
    _CACHE[key] = (catalog, field)          # holding `catalog` keeps its id() unique
    return field


def field_radius_rad(camera) -> float:
    """Largest angle between the boresight and a corner of the image (distortion included)."""
    w, h = camera.width_px - 0.5, camera.height_px - 0.5
    corners = np.array([[-0.5, -0.5], [w, -0.5], [-0.5, h], [w, h]])
    v = camera.unproject(corners)
    return float(np.max(np.arccos(np.clip(v[:, 0], -1.0, 1.0))))
