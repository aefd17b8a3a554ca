"""Apparent places of stars in the ship's horizontal frame (X north, Y up, Z east).

Two routes to the same directions, both on ERFA (SOFA algorithms, IAU 2006/2000A):

**Fast path** (:func:`frame_context`, what the pipeline uses): ``erfa.apco`` once per
frame time gives the star-independent parameters (Earth's barycentric position and
velocity, the site's geocentric position and velocity, bias-precession-nutation, Earth
rotation angle, polar motion) exactly as ``erfa.apco13`` does, except that the slowly
varying ephemeris and precession-nutation terms are interpolated between cached hourly
nodes (< 0.015 mas from ``erfa.atco13``); then for all stars at once, as ``erfa.atciq`` does but
keeping vectors: proper motion and parallax to the date (``erfa.pmpx``), light deflection
by the Sun (``erfa.ldsun``), aberration (``erfa.ab``, with the observer's total velocity,
so annual *and* diurnal aberration), and one 3x3 rotation CIRS -> horizontal that
reproduces ``erfa.atioq`` (Earth rotation, polar motion, site).  No refraction here: that
is :mod:`shipstar.sky.refraction`'s job, on the directions this module returns.

**Seed chain** (:func:`seed_chain`, seed 000 eq. 7, CIS -> MT -> CT -> ET -> CTS -> DP):
five named, individually testable rotation matrices (equinox-based: ``erfa.pmat06``,
``erfa.num06a``, GAST from ``erfa.gst06a``, ``erfa.pom00``, the site).  The chain is
purely geometric: applied to catalog directions it misses proper motion, parallax, light
deflection and aberration (up to ~21'' in all, see ``docs/sky-model.md``); applied to
aberrated GCRS directions it equals the fast path to < 1 microarcsecond.

The horizontal frame is the *astronomical* one (plumb line): the site's deflection of
the vertical (xi, eta) turns it by ``Phi = phi + xi``, ``Lambda = lambda + eta/cos(phi)``,
while the site's position (parallax, diurnal aberration) stays geodetic (WGS84).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.frames import rot_z, unit_from_ra_dec
from shipstar.sky.eop import EarthOrientation, earth_orientation
from shipstar.sky.time import tt_jd_from_utc_jd, ut1_jd_from_utc_jd
from shipstar.units import ASEC2RAD, DEG2RAD, J2000_JD, RAD2ASEC

__all__ = [
    "Site",
    "FrameContext",
    "frame_context",
    "SeedChain",
    "seed_chain",
    "C_hor_from_hadec",
    "C_hor_from_itrs",
    "MAX_DEFLECTION_ARCSEC",
    "HEIGHT_RANGE_M",
    "LON_RANGE_DEG",
]

#: Largest accepted deflection of the vertical component (arcsec); real ones are < 1'.
MAX_DEFLECTION_ARCSEC = 120.0
#: Accepted site heights above the WGS84 ellipsoid (m).
HEIGHT_RANGE_M = (-1000.0, 10000.0)
#: Accepted longitudes (deg) at the edges (:meth:`Site.from_deg`): east positive, or 0-360.
LON_RANGE_DEG = (-180.0, 360.0)
#: Longitudes in radians beyond this are refused (unwrapped tracks may pass +-180 deg).
_MAX_ABS_LON_RAD = 4.0 * math.pi
#: Julian dates accepted by :func:`frame_context` (1960-2100; the IERS tables limit further).
_MIN_JD, _MAX_JD = 2436934.5, 2488069.5


def _finite(value, name: str) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ShipstarError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(out):
        raise ShipstarError(f"{name} must be finite, got {value!r}")
    return out


# ---------------------------------------------------------------------------------------
# Site
# ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Site:
    """Observer's geodetic position (WGS84) and deflection of the vertical.

    Attributes
    ----------
    lat_rad, lon_rad : float
        Geodetic latitude and longitude (east positive; kept in (-pi, pi]).
    height_m : float
        Height above the WGS84 ellipsoid.
    xi_rad, eta_rad : float
        Deflection of the vertical: north-south (xi) and east-west (eta) components.
        Default 0 (the ellipsoid normal); a levelled ship or a dock's precision levels
        follow the plumb line, which differs from the normal by 5-30'' in most places.
    """

    lat_rad: float
    lon_rad: float
    height_m: float = 0.0
    xi_rad: float = 0.0
    eta_rad: float = 0.0

    def __post_init__(self):
        for name in ("lat_rad", "lon_rad", "height_m", "xi_rad", "eta_rad"):
            object.__setattr__(self, name, _finite(getattr(self, name), f"Site.{name}"))
        if abs(self.lat_rad) > 0.5 * math.pi:
            raise ShipstarError(f"latitude {self.lat_rad / DEG2RAD:.6g} deg is outside [-90, 90]")
        lo, hi = HEIGHT_RANGE_M
        if not lo <= self.height_m <= hi:
            raise ShipstarError(f"height {self.height_m} m is outside [{lo:.0f}, {hi:.0f}] m")
        for name in ("xi_rad", "eta_rad"):
            if abs(getattr(self, name)) > MAX_DEFLECTION_ARCSEC * ASEC2RAD:
                raise ShipstarError(
                    f"deflection of the vertical {name[:-4]} = {getattr(self, name) * RAD2ASEC:.6g} "
                    f"arcsec is outside +-{MAX_DEFLECTION_ARCSEC:.0f} arcsec")
        if abs(self.lat_rad + self.xi_rad) > 0.5 * math.pi:
            raise ShipstarError("astronomical latitude (latitude + xi) is beyond a pole")
        if self.eta_rad != 0.0 and math.cos(self.lat_rad) < 1e-6:
            raise ShipstarError("eta (east-west deflection) is undefined at a pole")
        if abs(self.lon_rad) > _MAX_ABS_LON_RAD:
            raise ShipstarError(f"longitude {self.lon_rad:.6g} rad is not a longitude")
        lon = math.remainder(self.lon_rad, 2.0 * math.pi)
        object.__setattr__(self, "lon_rad", lon + 2.0 * math.pi if lon <= -math.pi else lon)

    @classmethod
    def from_deg(cls, lat_deg, lon_deg, height_m=0.0, xi_arcsec=0.0, eta_arcsec=0.0) -> "Site":
        """Site from degrees (latitude, longitude east) and arcseconds (xi, eta).

        The longitude must lie within [-180, 360] deg (east positive, or 0-360); it is
        kept normalised to (-180, 180].
        """
        lon_deg = _finite(lon_deg, "longitude (deg)")
        lo, hi = LON_RANGE_DEG
        if not lo <= lon_deg <= hi:
            raise ShipstarError(f"longitude {lon_deg:.6g} deg is outside [{lo:.0f}, {hi:.0f}]")
        return cls(
            lat_rad=_finite(lat_deg, "latitude (deg)") * DEG2RAD,
            lon_rad=lon_deg * DEG2RAD,
            height_m=_finite(height_m, "height (m)"),
            xi_rad=_finite(xi_arcsec, "xi (arcsec)") * ASEC2RAD,
            eta_rad=_finite(eta_arcsec, "eta (arcsec)") * ASEC2RAD,
        )

    @property
    def astronomical_lat_rad(self) -> float:
        """``Phi = phi + xi``: latitude of the plumb line."""
        return self.lat_rad + self.xi_rad

    @property
    def astronomical_lon_rad(self) -> float:
        """``Lambda = lambda + eta / cos(phi)``: longitude of the plumb line."""
        if self.eta_rad == 0.0:
            return self.lon_rad
        return self.lon_rad + self.eta_rad / math.cos(self.lat_rad)


def C_hor_from_hadec(lat_rad: float) -> np.ndarray:
    """Rotation from ERFA's local (-HA, Dec) frame to the horizontal frame.

    ERFA's frame (``erfa.atioq``): X to the meridian on the equator (HA = 0), Y east
    (HA = -6 h), Z to the celestial pole.  Horizontal: X north, Y up, Z east::

        north = -sin(lat) X + cos(lat) Z,   up = cos(lat) X + sin(lat) Z,   east = Y
    """
    s, c = math.sin(lat_rad), math.cos(lat_rad)
    return np.array([[-s, 0.0, c], [c, 0.0, s], [0.0, 1.0, 0.0]])


def _C_hadec_from_cirs(astrom) -> np.ndarray:
    """ERFA's CIRS -> (-HA, Dec) rotation ``P(xpl, ypl) @ R_z(eral)`` (as ``erfa.atioq``)."""
    sx, cx = math.sin(astrom["xpl"]), math.cos(astrom["xpl"])
    sy, cy = math.sin(astrom["ypl"]), math.cos(astrom["ypl"])
    polar = np.array([[cx, 0.0, sx], [sx * sy, cy, -cx * sy], [-sx * cy, sy, cx * cy]])
    return polar @ rot_z(float(astrom["eral"]))


def _unit_rows(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _as_vectors(v, name: str) -> np.ndarray:
    arr = np.asarray(v, dtype=float)
    if arr.ndim == 0 or arr.shape[-1] != 3:
        raise ShipstarError(f"{name} must have shape (N, 3), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ShipstarError(f"{name} contains non-finite values")
    norm = np.linalg.norm(arr, axis=-1)
    if np.any(norm == 0.0):
        raise ShipstarError(f"{name} contains zero vectors")
    return arr / norm[..., None]


# ---------------------------------------------------------------------------------------
# Fast path
# ---------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class FrameContext:
    """Star-independent quantities for one frame time and site (one ``erfa.apco`` call).

    Attributes
    ----------
    utc_jd1, utc_jd2 : float
        Two-part UTC Julian date.
    site : Site
    eop : EarthOrientation
    astrom : numpy structured scalar
        ERFA's ``eraASTROM`` (no refraction: pressure 0).
    C_hor_from_cirs : ndarray, shape (3, 3)
        CIRS -> astronomical horizontal frame (Earth rotation, polar motion, site,
        deflection of the vertical), equal to ``erfa.atioq`` without refraction.
    C_hor_from_icrs_approx : ndarray, shape (3, 3)
        The rigid part of the map, ``C_hor_from_cirs @ bpn``: the best rigid rotation over
        the whole sky.  The true map is not rigid: aberration displaces each star by up to
        :attr:`aberration_arcsec` (~20.7'') toward the apex of the observer's motion, and
        by different amounts across even a small field (~3'' across 8 deg).  Use the
        per-star vectors (:meth:`hor_from_catalog`) for measurement.
    """

    utc_jd1: float
    utc_jd2: float
    site: Site
    eop: EarthOrientation
    astrom: np.ndarray = field(repr=False)
    C_hor_from_cirs: np.ndarray = field(repr=False)
    C_hor_from_icrs_approx: np.ndarray = field(repr=False)

    @property
    def aberration_arcsec(self) -> float:
        """Observer's barycentric speed / c, in arcsec: the largest aberration shift."""
        return float(np.linalg.norm(self.astrom["v"]) * RAD2ASEC)

    def hor_from_star_args(self, rc_rad, dc_rad, pr_rad_per_yr, pd_rad_per_yr, px_arcsec,
                           rv_km_s) -> np.ndarray:
        """Topocentric apparent directions ``(N, 3)`` from ERFA star arguments at J2000.0.

        Arguments as ``erfa.atciq`` takes them (``pr`` is dRA/dt, not times cos dec);
        each of shape ``(N,)`` (or broadcastable).  Negative parallaxes count as 0.
        No refraction.
        """
        import erfa

        a = self.astrom
        args = np.broadcast_arrays(*(np.asarray(x, float) for x in (
            rc_rad, dc_rad, pr_rad_per_yr, pd_rad_per_yr, px_arcsec, rv_km_s)))
        finite = np.isfinite(args[0])
        for arg in args[1:]:
            finite &= np.isfinite(arg)
        if not np.all(finite):
            bad = np.flatnonzero(~finite.reshape(-1))
            raise ShipstarError(f"{bad.size} star(s) have non-finite astrometry (first at index {bad[0]})")
        rc, dc, pr, pd, px, rv = args
        p = erfa.pmpx(rc, dc, pr, pd, np.maximum(px, 0.0), rv, a["pmt"], a["eb"])
        return self._hor_from_bcrs_direction(p)

    def _hor_from_bcrs_direction(self, p) -> np.ndarray:
        import erfa

        a = self.astrom
        p = erfa.ldsun(p, a["eh"], a["em"])
        p = erfa.ab(p, a["v"], a["em"], a["bm1"])
        return _unit_rows(p @ self.C_hor_from_icrs_approx.T)

    def hor_from_catalog(self, catalog, index=None) -> np.ndarray:
        """Topocentric apparent directions ``(N, 3)`` of catalog stars, NO refraction.

        Parameters
        ----------
        catalog : shipstar.sky.catalog.StarCatalog
        index : array_like of int or bool mask, optional
            Stars to use (default all).
        """
        args = catalog.erfa_args()
        if index is not None:
            idx = np.asarray(index)
            if idx.dtype == bool:
                if idx.shape != (len(catalog),):
                    raise ShipstarError(f"index mask has shape {idx.shape}, expected ({len(catalog)},)")
            elif idx.dtype.kind not in "iu":
                raise ShipstarError(f"index must be integers or a boolean mask, got {idx.dtype}")
            elif idx.size and (idx.min() < -len(catalog) or idx.max() >= len(catalog)):
                raise ShipstarError(f"index out of range for a catalog of {len(catalog)} stars")
            args = tuple(np.asarray(arg)[idx] for arg in args)
        return self.hor_from_star_args(*args)

    def hor_from_icrs(self, u_icrs) -> np.ndarray:
        """Apparent horizontal directions ``(N, 3)`` of bare ICRS directions ``(N, 3)``.

        No proper motion or parallax (the directions are taken as barycentric and
        infinitely far); light deflection and aberration are applied.  No refraction.
        """
        return self._hor_from_bcrs_direction(_as_vectors(u_icrs, "u_icrs"))

    def icrs_from_hor(self, v_hor) -> np.ndarray:
        """Inverse of :meth:`hor_from_icrs`: ICRS directions ``(N, 3)`` of horizontal ones.

        Removes aberration and light deflection with ``erfa.aticq`` (iterative, exact to
        well under a microarcsecond).
        """
        import erfa

        p_cirs = _as_vectors(v_hor, "v_hor") @ self.C_hor_from_cirs
        ri, di = erfa.c2s(p_cirs)
        rc, dc = erfa.aticq(ri, di, self.astrom)
        return unit_from_ra_dec(rc, dc)


#: Spacing (days, TT) of the cached nodes of the slowly varying star-independent terms
#: (Earth's barycentric position and velocity, CIP X, Y and CIO locator s).  Linear
#: interpolation between hourly nodes errs < 8 microarcsec in X, Y (short-period
#: nutation) and < 2 microarcsec in aberration; star places stay within 0.015 mas of
#: ``erfa.atco13`` (tested).
SLOW_NODE_SPACING_DAYS = 1.0 / 24.0
#: s' rate: -47 microarcseconds per Julian century (``erfa.sp00``).
_SP_RAD_PER_CENTURY = -47e-6 * ASEC2RAD


@functools.lru_cache(maxsize=256)
def _slow_node(k: int) -> np.ndarray:
    """``[eb (3), ebdot (3), eh (3), x, y, s]`` at TT = J2000 + k * SLOW_NODE_SPACING_DAYS.

    Earth's barycentric position (au) and velocity (au/day), heliocentric position (au)
    (``erfa.epv00``), and the CIP X, Y and CIO locator s (``erfa.xys06a``).
    """
    import erfa

    tt2 = k * SLOW_NODE_SPACING_DAYS
    pvh, pvb = erfa.epv00(J2000_JD, tt2)
    x, y, s = erfa.xys06a(J2000_JD, tt2)
    out = np.concatenate([pvb["p"], pvb["v"], pvh["p"], [x, y, s]])
    out.setflags(write=False)
    return out


def _slow_terms(tt1: float, tt2: float) -> np.ndarray:
    """The slow terms at a TT date, interpolated linearly between cached hourly nodes."""
    t = ((tt1 - J2000_JD) + tt2) / SLOW_NODE_SPACING_DAYS
    k = math.floor(t)
    f = t - k
    a, b = _slow_node(k), _slow_node(k + 1)
    return a + f * (b - a)


def _astrom(jd1: float, jd2: float, site: Site, eop: EarthOrientation):
    """ERFA's star-independent astrometry parameters, as ``erfa.apco13`` (no refraction).

    Identical to ``apco13`` except that Earth's ephemeris and the CIP come from
    :func:`_slow_terms` (apco13 evaluates ``epv00`` and the IAU 2006/2000A
    precession-nutation series, ~1400 terms, at every call).
    """
    import erfa

    tt1, tt2 = tt_jd_from_utc_jd(jd1, jd2)
    ut1, ut2 = ut1_jd_from_utc_jd(jd1, jd2, eop.dut1_s)
    slow = _slow_terms(tt1, tt2)
    theta = erfa.era00(ut1, ut2)
    sp = _SP_RAD_PER_CENTURY * ((tt1 - J2000_JD) + tt2) / 36525.0
    ebpv = np.ascontiguousarray(slow[0:6]).view(erfa.dt_pv)[0]     # (position, velocity)
    return erfa.apco(tt1, tt2, ebpv, slow[6:9], slow[9], slow[10], slow[11],
                     theta, site.lon_rad, site.lat_rad, site.height_m, eop.xp_rad, eop.yp_rad,
                     sp, 0.0, 0.0)


def frame_context(utc_jd1, utc_jd2, site: Site, eop: EarthOrientation | None = None) -> FrameContext:
    """Build the :class:`FrameContext` of one frame time (``erfa.apco`` once).

    Parameters
    ----------
    utc_jd1, utc_jd2 : float
        Two-part UTC Julian date.
    site : Site
    eop : EarthOrientation, optional
        Default: :func:`shipstar.sky.eop.earth_orientation` at this time (which warns
        when extrapolated).  Give one to fix UT1 - UTC and polar motion yourself.

    Raises
    ------
    ShipstarError
        Non-finite time, a wrong ``site``/``eop`` type, or a time outside the Earth
        orientation tables (when ``eop`` is not given).
    """
    jd1, jd2 = _finite(utc_jd1, "utc_jd1"), _finite(utc_jd2, "utc_jd2")
    if not isinstance(site, Site):
        raise ShipstarError(f"site must be a shipstar.sky.apparent.Site, got {type(site).__name__}")
    if eop is None:
        eop = earth_orientation(jd1, jd2)
    elif not isinstance(eop, EarthOrientation):
        raise ShipstarError(f"eop must be an EarthOrientation, got {type(eop).__name__}")
    if not _MIN_JD <= jd1 + jd2 <= _MAX_JD:
        raise ShipstarError(f"time JD {jd1 + jd2:.1f} is outside the years 1960-2100 shipstar models")
    astrom = _astrom(jd1, jd2, site, eop)
    # Deflection of the vertical: the plumb line's longitude and latitude.
    d_lon = site.astronomical_lon_rad - site.lon_rad
    C_hor_from_cirs = (C_hor_from_hadec(site.astronomical_lat_rad) @ rot_z(d_lon)
                       @ _C_hadec_from_cirs(astrom))
    C_approx = C_hor_from_cirs @ astrom["bpn"]
    for arr in (C_hor_from_cirs, C_approx):
        arr.setflags(write=False)
    return FrameContext(jd1, jd2, site, eop, astrom, C_hor_from_cirs, C_approx)


# ---------------------------------------------------------------------------------------
# Seed 000 eq. 7 chain
# ---------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class SeedChain:
    """Seed 000 eq. 7, ``R_CIS^DP = R_CTS^DP R_ET^CTS R_CT^ET R_MT^CT R_CIS^MT``, named.

    Attributes (all ``(3, 3)``)
    ---------------------------
    C_mean_from_icrs : CIS -> MT, frame bias and precession (``erfa.pmat06``)
    C_true_from_mean : MT -> CT, nutation IAU 2000A (``erfa.num06a``)
    C_pef_from_true : CT -> ET, Earth rotation ``R_z(GAST)`` (``erfa.gst06a``, UT1)
    C_itrs_from_pef : ET -> CTS, polar motion with s' (``erfa.pom00``)
    C_hor_from_itrs : CTS -> DP, the site: astronomical longitude and latitude
    gast_rad : Greenwich apparent sidereal time
    """

    C_mean_from_icrs: np.ndarray
    C_true_from_mean: np.ndarray
    C_pef_from_true: np.ndarray
    C_itrs_from_pef: np.ndarray
    C_hor_from_itrs: np.ndarray
    gast_rad: float

    @property
    def C_hor_from_icrs(self) -> np.ndarray:
        """The product: geometric ICRS (GCRS axes) -> horizontal rotation."""
        return (self.C_hor_from_itrs @ self.C_itrs_from_pef @ self.C_pef_from_true
                @ self.C_true_from_mean @ self.C_mean_from_icrs)


def C_hor_from_itrs(lat_rad: float, lon_rad: float) -> np.ndarray:
    """Site matrix: terrestrial (ITRS) -> horizontal at (astronomical) lat, lon.

    Rows are north, up and east in ITRS: ``C_hor_from_hadec(lat) @ R_z(lon)``.
    """
    return C_hor_from_hadec(lat_rad) @ rot_z(lon_rad)


def seed_chain(utc_jd1, utc_jd2, site: Site, eop: EarthOrientation | None = None) -> SeedChain:
    """The five named matrices of seed 000 eq. 7 at a UTC time and site."""
    import erfa

    jd1, jd2 = _finite(utc_jd1, "utc_jd1"), _finite(utc_jd2, "utc_jd2")
    if not isinstance(site, Site):
        raise ShipstarError(f"site must be a shipstar.sky.apparent.Site, got {type(site).__name__}")
    if eop is None:
        eop = earth_orientation(jd1, jd2)
    tt1, tt2 = tt_jd_from_utc_jd(jd1, jd2)
    ut1, ut2 = ut1_jd_from_utc_jd(jd1, jd2, eop.dut1_s)
    gast = float(erfa.gst06a(ut1, ut2, tt1, tt2))
    return SeedChain(
        C_mean_from_icrs=erfa.pmat06(tt1, tt2),
        C_true_from_mean=erfa.num06a(tt1, tt2),
        C_pef_from_true=rot_z(gast),
        C_itrs_from_pef=erfa.pom00(eop.xp_rad, eop.yp_rad, erfa.sp00(tt1, tt2)),
        C_hor_from_itrs=C_hor_from_itrs(site.astronomical_lat_rad, site.astronomical_lon_rad),
        gast_rad=gast,
    )
