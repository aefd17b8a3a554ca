"""Reference directions of catalog stars at the observation time (seed 002 sec. 3).

Interstar angles only need directions in *some* common frame, so:

- without a site: geocentric apparent places, ``erfa.atci13`` (proper motion and
  parallax to the date, light deflection, annual aberration; precession-nutation is a
  rotation and drops out of the angles), or with ``places="catalog"`` the bare ICRS
  directions with proper motion to the date (what ``shipstar simulate`` renders for a
  frame in space, which has no aberration);
- with a site: topocentric apparent places in the horizontal frame
  (:meth:`shipstar.sky.apparent.FrameContext.hor_from_catalog`, which adds diurnal
  aberration), then per-star refraction (:func:`shipstar.sky.refraction.refract_hor`)
  unless the model is ``"none"``.  Differential refraction across a 4 deg field at 45 deg
  elevation changes interstar angles by ~8'', far above the centroid noise.
"""

from __future__ import annotations

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.frames import unit_from_ra_dec

__all__ = ["reference_directions", "PLACES"]


def _catalog_index(catalog, hip) -> np.ndarray:
    hip = np.asarray(hip)
    if hip.ndim != 1 or hip.dtype.kind not in "iu":
        raise ShipstarError(f"hip must be a 1-D array of HIP numbers, got {hip!r}")
    return catalog.index_of_hip(hip)


PLACES = ("apparent", "catalog")


def reference_directions(hip, utc_jd1: float, utc_jd2: float, *, catalog=None, site=None,
                         weather=None, refraction_model: str = "erfa", eop=None,
                         places: str = "apparent") -> np.ndarray:
    """Unit directions ``(N, 3)`` of Hipparcos stars as a sensor sees them.

    Parameters
    ----------
    hip : array_like of int, shape (N,)
    utc_jd1, utc_jd2 : float
        Two-part UTC Julian date of mid-exposure.
    catalog : StarCatalog, optional
        Default: the full Hipparcos catalog (:func:`shipstar.sky.catalog.load_hipparcos`).
    site : shipstar.sky.apparent.Site, optional
        Observer on the ground; without it, geocentric apparent places (no refraction).
    weather : shipstar.sky.refraction.Weather, optional
        With a site: the conditions for refraction (default: standard atmosphere).
    refraction_model : str
        ``"almanac"``, ``"erfa"`` or ``"none"`` (see :mod:`shipstar.sky.refraction`).
    eop : EarthOrientation, optional
        With a site: UT1 - UTC and polar motion (default from the IERS tables).
    places : {"apparent", "catalog"}
        Without a site: geocentric apparent places (default) or catalog directions with
        proper motion only.

    Returns
    -------
    ndarray (N, 3)
        Geocentric apparent (ICRS-aligned CIRS) or topocentric horizontal directions.
    """
    import erfa

    from shipstar.sky.time import quiet_dubious_year, tt_jd_from_utc_jd

    if catalog is None:
        from shipstar.sky.catalog import load_hipparcos

        catalog = load_hipparcos()
    if places not in PLACES:
        raise ShipstarError(f"places must be one of {', '.join(PLACES)}, got {places!r}")
    idx = _catalog_index(catalog, hip)
    if site is None:
        if weather is not None:
            raise ShipstarError("refraction needs a site: give the site with the weather")
        if places == "catalog":
            from shipstar.units import J2000_JD, JULIAN_YEAR_DAYS

            epoch = 2000.0 + (utc_jd1 - J2000_JD + utc_jd2) / JULIAN_YEAR_DAYS
            return catalog.subset(idx).unit_icrs(epoch)
        tt1, tt2 = tt_jd_from_utc_jd(utc_jd1, utc_jd2)
        args = tuple(np.asarray(a)[idx] for a in catalog.erfa_args())
        px = np.maximum(args[4], 0.0)
        with quiet_dubious_year():
            ri, di, _eo = erfa.atci13(args[0], args[1], args[2], args[3], px, args[5], tt1, tt2)
        return unit_from_ra_dec(ri, di)
    if places != "apparent":
        raise ShipstarError("catalog places are for frames without a site (in space)")
    from shipstar.sky.apparent import frame_context
    from shipstar.sky.refraction import MODELS, Weather, refract_hor

    if refraction_model not in MODELS:
        raise ShipstarError(f"refraction model must be one of {', '.join(MODELS)}, got {refraction_model!r}")
    ctx = frame_context(utc_jd1, utc_jd2, site, eop)
    v = ctx.hor_from_catalog(catalog, idx)
    if refraction_model == "none":
        return v
    return refract_hor(v, Weather() if weather is None else weather, refraction_model)
