"""Deep matching: once a frame is identified, name every other detected star too.

Identification works with a navigation database that stops at Hp ~7.3 (35 stars a
field), so in an A1 frame about half of the detected stars stay unnamed.  With the
attitude known to about an arcsecond, every other detection can be looked up in a
*deeper* catalog (Hipparcos to the sensor's limiting magnitude, close pairs excluded by
:func:`~shipstar.sky.catalog.navigation_catalog`'s rule) by prediction alone:

1. **Local model.** The catalog stars of the identified detections are projected with
   the attitude into the sensor's tangent plane; the offsets measured minus predicted
   are fitted, weighted by the centroid errors, by an affine map ``d = a + B t`` (shift,
   rotation, and the non-rigid scale/shear that differential refraction and aberration
   or a focal-length error leave in a rigid ICRS fit: up to +-11'' at the edges of an
   8 deg field at 40 deg elevation).  Identified stars beyond ``k_sigma`` of the fit are
   left out of it; ``kappa`` (``sigma_scale``) scales the given centroid errors up when
   the residuals say they are too small (median of ``|r|^2 / sigma^2`` against the
   chi-square(2) median ``2 ln 2``).
2. **Gates.** Every catalog star of the field is predicted with the local model; the
   gate of detection ``i`` is ``gate_sigma * sqrt(kappa^2 sigma_i^2 + var_pred)``
   (``var_pred``: the fit's own prediction variance at that place).
3. **Pairs.** A detection not identified is paired with the catalog star within its
   gate only if that star is the *only* one there, no other detection (identified or
   not) has it within its gate, and identification has not named it already: a false
   detection near a faint catalog star next to a real one, a split or blended image,
   a crowded spot are all left unmatched (``n_ambiguous``).
4. **Chance.** A detection that is not a catalog star (a false detection, a star fainter
   than the catalog) lands within ``g_i`` of one of the field's catalog stars with
   probability ``rho pi g_i^2`` (``rho``: catalog stars per unit tangent-plane area in
   the field).  ``expected_chance = sum_i rho pi g_i^2`` over the detections offered
   for pairing (an upper bound: most of them are the catalog's stars).  When it would
   exceed ``max_chance`` the largest gates - the poorest measured detections', which
   weigh least - are capped at the one value that brings it to ``max_chance``
   (``gate_max_arcsec``).
5. **Attitude.** The weighted attitude over all matched stars, ``sigma_rad = kappa
   sigma_i`` per star, with outlier rejection: the solution and rejection rule of
   :func:`shipstar.attitude.solve_attitude` (the tests check both agree), on its fast
   path (``quest_single`` and plain floats: solve_attitude's input checks cost 0.25-0.5 ms
   for 40-120 stars, more than everything else here).  The measured directions lose the
   fitted non-rigid part first when it is significant (the affine fit's chi-square
   below the rigid fit's by more than chi-square(3)'s 99.9 % point, 16.27).  Added
   stars the solve rejects are unmatched again and not offered again.
6. **Once more.** The field is predicted with the solved attitude (plus the non-rigid
   part), pairs are made again, and the attitude solved again if they changed.

Identification's own stars are never renamed or removed (an identified star the solve
rejects keeps its HIP number and has ``inliers`` False).  See docs/identification.md,
*Deep matching*.
"""

from __future__ import annotations

import math
import time
import weakref
from dataclasses import dataclass

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.identify._result import ra_dec_roll_deg
from shipstar.units import ASEC2RAD

__all__ = ["DeepMatch", "deep_match", "deep_catalog", "DEEP_MAG_LIMIT"]

#: Default faintest Hp of the deep catalog: A1 detects stars to Hp ~8.4 (5 sigma) and
#: Hipparcos is complete to Hp ~7.3-9, so every detectable Hipparcos star is in it.
DEEP_MAG_LIMIT = 9.0
#: chi-square with 3 degrees of freedom, 99.9 % point (significance of the non-rigid part)
_CHI2_3_P999 = 16.266
#: median of a chi-square(2) variable
_CHI2_2_MEDIAN = 2.0 * math.log(2.0)
#: identified stars needed to fit the affine local model (fewer: a shift only)
_MIN_AFFINE = 6
#: catalog positions are propagated again when the epoch moves further than this (yr);
#: within it they move linearly (the straight-line motion's curvature over a year is
#: below 0.01 mas for every Hipparcos star)
_EPOCH_SPAN_YR = 1.0
#: margin of the field cone beyond the outermost detection (rad): ~20''
_FIELD_MARGIN_RAD = 1e-4


@dataclass(frozen=True, eq=False)
class DeepMatch:
    """Identification extended to every detected star a deeper catalog can name.

    It carries the fields of :class:`~shipstar.identify.Identification` that later steps
    use (``solved``, ``reason``, ``mode``, ``C_icrs_from_sensor``, ``hip``, ``u_sensor``,
    ``n_matched``, ``rms_arcsec``, ``focal_scale``, ``radial_k1``), with the same meaning.

    Attributes
    ----------
    solved : bool
        False when the identification was not solved or the attitude could not be
        re-solved (then every star is unmatched and every number NaN: keep the
        identification).
    reason : str
        Why not ("" when solved).
    mode : str
        The identification's mode (``"lost_in_space"`` or ``"tracking"``).
    C_icrs_from_sensor : ndarray (3, 3)
        Attitude from every matched star, weighted by ``sigma^-2`` with outlier rejection
        (``solve_attitude``'s solution); the rigid part of the catalog-to-image map.
    hip : ndarray (N,), int64
        HIP number of each input star, -1 if unmatched: the identification's, plus the
        added ones.
    catalog_index : ndarray (N,), int64
        Row of each matched star in the deep catalog, -1 if unmatched.
    added : ndarray (N,), bool
        Stars matched by deep matching (not by the identification).
    inliers : ndarray (N,), bool
        Stars used in the final attitude.
    u_sensor : ndarray (N, 3)
        Measured sensor-frame unit vectors (at the identification's focal scale).
    n_identified, n_matched, n_added : int
        Stars named by the identification, in all, and added.
    n_ambiguous : int
        Detections with a catalog star in their gate left unmatched as ambiguous.
    n_rejected : int
        Added pairs the attitude solve rejected as outliers (unmatched again).
    expected_chance : float
        Expected number of chance pairs among the detections offered for pairing
        (``sum rho pi g_i^2``), at the gates used.
    gate_max_arcsec : float
        Cap on the gates that keeps ``expected_chance <= max_chance`` (inf: no cap; the
        poorest measured detections' gates are the ones capped).
    sigma_scale : float
        ``kappa``: factor applied to the given centroid errors (>= 1).
    nonrigid : ndarray (2, 2)
        Symmetric linear part (scale, shear) of the tangent-plane map removed from the
        measured directions before the solve; zeros when not significant.
    covariance_rad2 : ndarray (3, 3)
        Attitude error covariance about the sensor axes (X boresight: roll).
    rms_arcsec : float
        RMS residual of the stars used.
    focal_scale, radial_k1 : float
        The identification's.
    time_s : float
        Wall time of the deep matching.
    """

    solved: bool
    reason: str
    mode: str
    C_icrs_from_sensor: np.ndarray
    hip: np.ndarray
    catalog_index: np.ndarray
    added: np.ndarray
    inliers: np.ndarray
    u_sensor: np.ndarray
    n_identified: int
    n_matched: int
    n_added: int
    n_ambiguous: int
    n_rejected: int
    expected_chance: float
    gate_max_arcsec: float
    sigma_scale: float
    nonrigid: np.ndarray
    covariance_rad2: np.ndarray
    rms_arcsec: float
    focal_scale: float
    radial_k1: float
    time_s: float

    @property
    def ra_dec_roll_deg(self) -> tuple[float, float, float]:
        """Boresight RA, Dec and roll (docs/conventions.md) in degrees (NaN if not solved)."""
        return ra_dec_roll_deg(self.solved, self.C_icrs_from_sensor)


def _failed(n: int, mode: str, reason: str, u, idn, t0: float) -> DeepMatch:
    nan33 = np.full((3, 3), np.nan)
    return DeepMatch(
        solved=False, reason=reason, mode=mode, C_icrs_from_sensor=nan33,
        hip=np.full(n, -1, np.int64), catalog_index=np.full(n, -1, np.int64),
        added=np.zeros(n, bool), inliers=np.zeros(n, bool), u_sensor=u, n_identified=0,
        n_matched=0, n_added=0, n_ambiguous=0, n_rejected=0, expected_chance=math.nan,
        gate_max_arcsec=math.nan, sigma_scale=math.nan, nonrigid=np.full((2, 2), np.nan),
        covariance_rad2=nan33.copy(), rms_arcsec=math.nan, focal_scale=float(idn.focal_scale),
        radial_k1=float(idn.radial_k1), time_s=time.perf_counter() - t0)


# ------------------------------------------------------------------------------------
# The deep catalog and its sky index
# ------------------------------------------------------------------------------------

def deep_catalog(database, mag_limit: float = DEEP_MAG_LIMIT):
    """The deep catalog for a navigation database: Hipparcos to ``mag_limit``, with the
    database's close-pair rule (``navigation_catalog(mag_limit,
    database.params.min_separation_arcsec)``, cached on disk).

    With the same close-pair rule and a limit at least the database's, every database
    star is in it (the rule judges a star by its neighbours only), so every star an
    identification names can be looked up.

    Parameters
    ----------
    database : StarDatabase
    mag_limit : float
        Faintest Hp (at least the database's own limit is used).
    """
    from shipstar.sky.catalog import navigation_catalog

    params = getattr(database, "params", None)
    if params is None or not hasattr(params, "min_separation_arcsec"):
        raise ShipstarError(f"database must be a StarDatabase (see build_database), got "
                            f"{type(database).__name__}")
    limit = _finite(mag_limit, "mag_limit")
    return navigation_catalog(max(limit, float(params.mag_limit)), float(params.min_separation_arcsec))


#: a field looked up is padded by this (rad, 0.5 deg) and kept: a tracked sensor's next
#: frames fall inside it
_FIELD_PAD_RAD = 0.0087
#: cached field vectors are reused while the epoch moves them by less than this (rad)
_FIELD_EPOCH_TOL_RAD = 1e-11


class _SkyIndex:
    """A catalog's unit vectors at a reference epoch, their yearly motion, a KD-tree and
    the last field looked up."""

    __slots__ = ("epoch", "u0", "du", "tree", "max_du", "last", "hip_order", "hip_sorted", "__weakref__")

    def __init__(self, catalog, epoch: float):
        from scipy.spatial import cKDTree

        self.hip_order = np.argsort(catalog.hip, kind="stable")
        self.hip_sorted = catalog.hip[self.hip_order]
        self.epoch = epoch
        self.u0 = catalog.unit_icrs(epoch)
        self.du = catalog.unit_icrs(epoch + 1.0) - self.u0          # per Julian year
        self.max_du = float(np.sqrt(np.max(np.einsum("ij,ij->i", self.du, self.du), initial=0.0)))
        self.tree = cKDTree(self.u0)
        self.last = None

    def rows_of_hip(self, hip) -> np.ndarray:
        """Catalog rows of HIP numbers ``(k,)``; ShipstarError naming those not in it."""
        hip = np.asarray(hip, np.int64)
        pos = np.minimum(np.searchsorted(self.hip_sorted, hip), max(self.hip_sorted.size - 1, 0))
        found = self.hip_sorted[pos] == hip if self.hip_sorted.size else np.zeros(hip.shape, bool)
        if not found.all():
            missing = ", ".join(str(h) for h in hip[~found][:5]) + (" ..." if np.count_nonzero(~found) > 5 else "")
            raise ShipstarError(f"the deep catalog lacks identified stars (HIP {missing}): build it with "
                                "deep_catalog(database)")
        return self.hip_order[pos]

    def vectors(self, rows, epoch: float) -> np.ndarray:
        """Unit vectors ``(k, 3)`` of catalog ``rows`` at ``epoch``."""
        u = self.u0[rows] + self.du[rows] * (epoch - self.epoch)
        return u / np.sqrt(np.einsum("ij,ij->i", u, u))[:, None]

    def field(self, direction, radius_rad: float, epoch: float):
        """``(rows (M,) ascending, u (M, 3) at epoch, radius_rad used)``: every catalog
        star within ``radius_rad`` of the unit vector ``direction`` (the cone used may be
        larger: the last one, padded, while it covers this one; read-only arrays)."""
        x, y, z = (float(c) for c in direction)
        last = self.last
        if last is not None:
            (cx, cy, cz), r_last, e_last, rows, u = last
            apart = math.acos(max(-1.0, min(1.0, x * cx + y * cy + z * cz)))
            if apart + radius_rad <= r_last and abs(epoch - e_last) * self.max_du <= _FIELD_EPOCH_TOL_RAD:
                return rows, u, r_last
        r = min(radius_rad + _FIELD_PAD_RAD, 0.5 * math.pi)
        r_search = r + self.max_du * abs(epoch - self.epoch)        # the tree holds u0
        rows = np.sort(np.asarray(self.tree.query_ball_point((x, y, z), 2.0 * math.sin(0.5 * r_search)),
                                  dtype=np.intp))
        u = self.vectors(rows, epoch)
        rows.setflags(write=False)
        u.setflags(write=False)
        self.last = ((x, y, z), r, epoch, rows, u)
        return rows, u, r


_INDEX: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _sky_index(catalog, epoch: float) -> _SkyIndex:
    hit = _INDEX.get(catalog)
    if hit is None or abs(epoch - hit.epoch) > _EPOCH_SPAN_YR:
        hit = _INDEX[catalog] = _SkyIndex(catalog, epoch)
    return hit


# ------------------------------------------------------------------------------------
# Inputs
# ------------------------------------------------------------------------------------

def _finite(value, name: str) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ShipstarError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(out):
        raise ShipstarError(f"{name} must be finite, got {value!r}")
    return out


def _measured(stars, n: int, camera, pixel_scale_arcsec, idn):
    """``(t (N, 2), u (N, 3), scale_rad)``: tangent-plane coordinates and unit vectors of
    the measured stars at the identification's focal scale, and the pixel scale."""
    try:
        arr = np.asarray(stars, dtype=float)
    except (TypeError, ValueError):
        raise ShipstarError("stars must be an (N, 3) array of unit vectors or (N, 2) pixel positions") from None
    if arr.ndim != 2 or arr.shape[1] not in (2, 3) or arr.shape[0] != n:
        raise ShipstarError(f"stars must have shape ({n}, 3) or ({n}, 2) like the identification, "
                            f"got {arr.shape}")
    if camera is not None:
        scale = float(camera.pixel_mm) / float(camera.f_mm)
    elif arr.shape[1] == 2:
        raise ShipstarError("pixel positions need the camera (camera=...)")
    elif pixel_scale_arcsec is None:
        raise ShipstarError("unit vectors need camera=... or pixel_scale_arcsec=... (to convert sigma_px)")
    else:
        scale = _finite(pixel_scale_arcsec, "pixel_scale_arcsec") * ASEC2RAD
        if scale <= 0.0:
            raise ShipstarError(f"pixel_scale_arcsec must be > 0, got {pixel_scale_arcsec}")
    if arr.shape[1] == 2:
        u = camera.unproject(arr)                               # unit, in front (NaN rows for NaN)
        t = u[:, 1:] / u[:, :1]
        s, k1 = float(idn.focal_scale), float(idn.radial_k1)
        if s != 1.0 or k1 != 0.0:
            t = t * (s * (1.0 + k1 * np.einsum("ij,ij->i", t, t)))[:, None]
    else:
        with np.errstate(invalid="ignore", divide="ignore"):
            t = arr[:, 1:] / arr[:, :1]
        t[~(arr[:, 0] > 0.0)] = np.nan
    u = np.empty((n, 3))
    u[:, 0] = 1.0
    u[:, 1:] = t
    u /= np.sqrt(np.einsum("ij,ij->i", u, u))[:, None]
    return t, u, scale


def _sigma(sigma_px, n: int) -> np.ndarray:
    try:
        s = np.asarray(sigma_px, dtype=float)
    except (TypeError, ValueError):
        raise ShipstarError("sigma_px must be numbers (pixels)") from None
    if s.shape != (n,):
        raise ShipstarError(f"sigma_px must have shape ({n},), got {s.shape}")
    if not np.all(np.isfinite(s) & (s > 0.0)):
        raise ShipstarError("sigma_px must be finite and > 0 for every star (give saturated stars, "
                            "whose extraction sigma is NaN, a value such as 1 px)")
    return s


def _check_options(epoch_jyear, gate_sigma, max_chance, k_sigma) -> tuple[float, float, float, float]:
    epoch = _finite(epoch_jyear, "epoch_jyear")
    if not 1000.0 <= epoch <= 3000.0:
        raise ShipstarError(f"epoch_jyear must be a Julian year such as 2025.0, got {epoch_jyear!r}")
    gate = _finite(gate_sigma, "gate_sigma")
    if not 1.0 <= gate <= 20.0:
        raise ShipstarError(f"gate_sigma must be within 1 .. 20, got {gate_sigma}")
    chance = _finite(max_chance, "max_chance")
    if not 0.0 < chance <= 1.0:
        raise ShipstarError(f"max_chance must be within (0, 1], got {max_chance}")
    k = _finite(k_sigma, "k_sigma")
    if k <= 0.0:
        raise ShipstarError(f"k_sigma must be > 0, got {k_sigma}")
    return epoch, gate, chance, k


# ------------------------------------------------------------------------------------
# The local model (tangent plane)
# ------------------------------------------------------------------------------------

def _inv3(m) -> np.ndarray:
    """Inverse of a symmetric positive definite (3, 3) matrix by the adjugate, in plain
    floats (a LAPACK call can wait milliseconds for its thread pool on a busy machine);
    ShipstarError when it is singular (``det <= 1e-14 tr^3``, as
    :func:`shipstar.attitude.attitude_covariance`)."""
    (a, b, c), (_, d, e), (_, _, f) = m.tolist()
    A, B, Cc = d * f - e * e, c * e - b * f, b * e - c * d
    det = a * A + b * B + c * Cc
    if not (math.isfinite(det) and det > 1e-14 * (a + d + f) ** 3):
        raise ShipstarError("singular 3 x 3 normal matrix")
    return np.array([[A, B, Cc], [B, a * f - c * c, b * c - a * e], [Cc, b * c - a * e, a * d - b * b]]) / det


def _project(v, C) -> np.ndarray:
    """Tangent-plane coordinates ``(k, 2)`` of ICRS unit vectors ``v`` seen with ``C``."""
    w = v @ C
    return w[:, 1:] / w[:, :1]


class _Local:
    """Weighted affine fit ``d = a + B t`` of measured minus predicted offsets."""

    __slots__ = ("beta", "n_inv", "kappa2", "nonrigid")

    def __init__(self, t, d, sig2, k_sigma: float):
        w = 1.0 / sig2
        keep = np.ones(t.shape[0], bool)
        for fit in range(3):
            n_mat, rhs = self._fit(t[keep], d[keep], w[keep])
            r = d - self.predict_offset(t)
            z2 = np.einsum("ij,ij->i", r, r) * w
            self.kappa2 = max(1.0, float(np.median(z2[keep])) / _CHI2_2_MEDIAN)
            bad = keep & (z2 > k_sigma * k_sigma * self.kappa2)
            if fit == 2 or not bad.any() or keep.sum() - bad.sum() < 2:
                break
            keep &= ~bad
        self.nonrigid = self._significant_nonrigid(n_mat, rhs)

    def _fit(self, t, d, w):
        """Weighted least squares; returns the normal matrix and right-hand side."""
        if t.shape[0] >= _MIN_AFFINE:
            x = np.ones((t.shape[0], 3))
            x[:, 1:] = t
            xw = x * w[:, None]
            n_mat, rhs = x.T @ xw, xw.T @ d                   # (3, 3), (3, 2)
            try:
                self.n_inv = _inv3(n_mat)
                self.beta = self.n_inv @ rhs                  # rows: a, then B^T
                return n_mat, rhs
            except ShipstarError:                             # stars on a line: a shift only
                pass
        n_mat = np.array([[w.sum()]])
        rhs = (w @ d)[None, :]
        self.n_inv = 1.0 / n_mat
        self.beta = self.n_inv @ rhs
        return n_mat, rhs

    def predict_offset(self, t) -> np.ndarray:
        if self.beta.shape[0] == 1:
            return np.broadcast_to(self.beta[0], t.shape)
        return self.beta[0] + t @ self.beta[1:]

    def variance(self, t) -> np.ndarray:
        """Prediction variance ``(k,)`` per axis at ``t`` (scaled by ``kappa^2``)."""
        if self.beta.shape[0] == 1:
            return np.full(t.shape[0], self.n_inv[0, 0] * self.kappa2)
        x = np.empty((t.shape[0], 3))
        x[:, 0] = 1.0
        x[:, 1:] = t
        return np.einsum("ij,jk,ik->i", x, self.n_inv, x) * self.kappa2

    def _significant_nonrigid(self, n_mat, rhs) -> np.ndarray:
        """The symmetric part of ``B`` if the affine fit beats the rigid one (shift and
        rotation ``phi``: ``d = a + phi (-t_z, t_y)``) by more than chi-square(3)'s 99.9 %
        point, else zeros.  Both fits' explained sums of squares come from the affine
        fit's normal matrix ``X^T W X`` (``X = [1, t_y, t_z]``) and ``X^T W d``."""
        if self.beta.shape[0] == 1:
            return np.zeros((2, 2))
        (sw, swy, swz), (_, syy, syz), (_, _, szz) = n_mat.tolist()
        n_rigid = np.array([[sw, 0.0, -swz], [0.0, sw, swy], [-swz, swy, syy + szz]])
        rhs_rigid = np.array([rhs[0, 0], rhs[0, 1], rhs[1, 1] - rhs[2, 0]])
        explained_rigid = float(rhs_rigid @ _inv3(n_rigid) @ rhs_rigid)
        explained_aff = float(np.einsum("ia,ij,ja->", rhs, self.n_inv, rhs))
        if explained_aff - explained_rigid <= _CHI2_3_P999 * self.kappa2:
            return np.zeros((2, 2))
        b = self.beta[1:].T                                   # B[a, b] = d(offset_a) / d(t_b)
        return 0.5 * (b + b.T)


# ------------------------------------------------------------------------------------
# Pairing
# ------------------------------------------------------------------------------------

#: the band searched around each detection is this much wider than the largest gate, so
#: that the pairs' margin (below) covers every star that could enter a gate
_BAND_SLACK = 0.25


def _pair(t_det, g2, offered, t_pred, claimed):
    """New pairs ``(det (k,), star (k,))``, the number of ambiguous detections, and the
    margin: no prediction moved by less than it changes which stars are in which gates.

    ``t_det`` (F, 2): usable detections, each with its squared gate ``g2`` (F,);
    ``offered`` (F,) bool: those that may be paired; ``t_pred`` (M, 2): predicted
    catalog stars, ``claimed`` (M,) bool: named by the identification.  A detection pairs
    with a star when that star is the only one within its gate, no other detection has
    it within its own gate, and it is not claimed.

    The stars near each detection are found in the predictions sorted by their first
    coordinate: those within 1.25 times the largest gate of it in that coordinate (a
    band a few arcseconds wide holds a few stars at most), gathered as an ``(F, width)``
    array.  The margin is the smallest ``|distance - gate|`` over them (stars outside
    the band are at least 0.25 times the largest gate beyond every gate).
    """
    m = t_pred.shape[0]
    if m == 0 or not offered.any():
        return np.empty(0, np.intp), np.empty(0, np.intp), 0, math.inf
    order = np.argsort(t_pred[:, 0])
    py = t_pred[order, 0]
    g_max = math.sqrt(float(g2.max()))
    band = (1.0 + _BAND_SLACK) * g_max
    lo = np.searchsorted(py, t_det[:, 0] - band, "left")
    hi = np.searchsorted(py, t_det[:, 0] + band, "right")
    width = int((hi - lo).max())
    if width == 0:
        return np.empty(0, np.intp), np.empty(0, np.intp), 0, _BAND_SLACK * g_max
    at = lo[:, None] + np.arange(width)
    valid = at < hi[:, None]
    star = order[np.minimum(at, m - 1)]                       # (F, width)
    dy = t_det[:, :1] - t_pred[star, 0]
    dz = t_det[:, 1:] - t_pred[star, 1]
    d2 = dy * dy + dz * dz
    inside = valid & (d2 <= g2[:, None])
    per_det = inside.sum(axis=1)
    per_star = np.bincount(star[inside], minlength=m)
    rows = np.flatnonzero(offered & (per_det >= 1))
    first = star[rows, np.argmax(inside[rows], axis=1)]
    ok = (per_det[rows] == 1) & (per_star[first] == 1) & ~claimed[first]
    gap = np.abs(np.sqrt(d2[valid]) - np.sqrt(np.broadcast_to(g2[:, None], d2.shape)[valid]))
    margin = min(float(gap.min()) if gap.size else math.inf, _BAND_SLACK * g_max)
    return rows[ok], first[ok], int(rows.size - np.count_nonzero(ok)), margin


def _gates(var, offered, gate_sigma: float, rho: float, max_chance: float):
    """Squared gates ``(F,)``, the cap on them (tangent units, inf if none) and the
    expected number of chance pairs.

    ``var``: each usable detection's variance of measured minus predicted position per
    axis.  Gates are ``gate_sigma`` sigmas; when the expected chance pairs of the
    offered detections, ``rho pi sum g^2``, would exceed ``max_chance``, the largest
    gates (the poorest measured stars, which carry the least weight) are capped at the
    one value that brings it to ``max_chance``.
    """
    g2 = gate_sigma * gate_sigma * var
    go = g2[offered]
    total = float(go.sum())
    target = max_chance / (rho * math.pi)
    if total <= target:
        return g2, math.inf, rho * math.pi * total
    go.sort()
    below = np.concatenate(([0.0], np.cumsum(go)[:-1]))          # sum of the k smallest
    cap = (target - below) / (go.size - np.arange(go.size))    # sum min(g2, cap) = target
    lower = np.concatenate(([0.0], go[:-1]))
    k = int(np.argmax((cap <= go) & (cap >= lower)))
    cap2 = float(cap[k])
    g2 = np.where(offered, np.minimum(g2, cap2), g2)
    return g2, math.sqrt(cap2), max_chance


# ------------------------------------------------------------------------------------
# The frame
# ------------------------------------------------------------------------------------

class _Frame:
    """Measured stars and the field's catalog stars of one frame.

    Attributes (beyond the inputs): ``usable`` rows of finite detections and their
    tangent-plane coordinates ``t_det``; ``cat`` / ``v`` the identification's catalog
    rows and vectors (N,) / (N, 3); the field's catalog ``field_rows`` / ``field_u``,
    ``claimed`` (named by the identification) and density ``rho`` (stars per unit
    tangent-plane area); ``excluded``: added pairs a solve rejected (not offered again).
    """

    def __init__(self, t_m, u_m, sig_rad, idn, catalog, index, epoch):
        n = t_m.shape[0]
        self.t_m, self.u_m, self.sig_rad, self.sig2 = t_m, u_m, sig_rad, sig_rad * sig_rad
        self.catalog_hip = catalog.hip
        self.usable = np.flatnonzero(np.isfinite(t_m[:, 0] + t_m[:, 1]))
        self.t_det = t_m[self.usable]
        ident = np.flatnonzero(np.asarray(idn.hip) >= 0)
        self.ident = ident
        self.cat = np.full(n, -1, np.int64)
        self.cat[ident] = index.rows_of_hip(np.asarray(idn.hip)[ident])
        self.v = np.full((n, 3), np.nan)
        self.v[ident] = index.vectors(self.cat[ident], epoch)
        cos_max = float(u_m[self.usable, 0].min()) if self.usable.size else 1.0
        radius = math.acos(min(1.0, max(-1.0, cos_max))) + _FIELD_MARGIN_RAD
        self.field_rows, self.field_u, radius = index.field(np.asarray(idn.C_icrs_from_sensor, float)[:, 0],
                                                            radius, epoch)
        self.claimed = np.zeros(self.field_rows.size, bool)
        if self.field_rows.size:
            rows_i = self.cat[ident]
            pos = np.minimum(np.searchsorted(self.field_rows, rows_i), self.field_rows.size - 1)
            self.claimed[pos[self.field_rows[pos] == rows_i]] = True
        self.rho = self.field_rows.size / (math.pi * math.tan(radius) ** 2)
        self.excluded = np.zeros(n, bool)
        self.offered0 = np.ones(n, bool)
        self.offered0[ident] = False

    def local_model(self, C, k_sigma: float) -> _Local:
        """The affine local model of the identified stars seen with ``C``."""
        t_p = _project(self.v[self.ident], C)
        return _Local(t_p, self.t_m[self.ident] - t_p, self.sig2[self.ident], k_sigma)

    def variance(self, local: _Local) -> np.ndarray:
        """Variance per axis of measured minus predicted position of each usable detection."""
        return self.sig2[self.usable] * local.kappa2 + local.variance(self.t_det)

    def new_pairs(self, t_pred, var, gate_sigma, max_chance):
        """Pairs for predicted field stars ``t_pred`` (M, 2): ``(det rows, catalog rows,
        catalog vectors, n_ambiguous, gate cap, expected chance, margin)`` (see
        :func:`_pair` for the margin)."""
        offered = (self.offered0 & ~self.excluded)[self.usable]
        g2, cap, chance = _gates(var, offered, gate_sigma, self.rho, max_chance)
        k, star, n_amb, margin = _pair(self.t_det, g2, offered, t_pred, self.claimed)
        return self.usable[k], self.field_rows[star], self.field_u[star], n_amb, cap, chance, margin

    def solve(self, det, rows, v_new, local, k_sigma, C_near):
        """Weighted robust attitude over identified + new pairs: ``(_Solution, matched
        rows, catalog rows (N,))``."""
        cat = self.cat.copy()
        v = self.v.copy()
        cat[det], v[det] = rows, v_new
        m = np.flatnonzero(cat >= 0)
        u = self.u_m[m]
        s = local.nonrigid
        if s.any():                                             # remove the non-rigid part
            t = self.t_m[m]
            u = np.empty((m.size, 3))
            u[:, 0] = 1.0
            u[:, 1:] = t - t @ s.T
            u /= np.sqrt(np.einsum("ij,ij->i", u, u))[:, None]
        sol = _robust_attitude(u, v[m], self.sig_rad[m] * math.sqrt(local.kappa2), k_sigma, C_near)
        return sol, m, cat


class _Solution:
    """``C_icrs_from_sensor``, inliers, covariance and RMS of :func:`_robust_attitude`."""

    __slots__ = ("solved", "reason", "C", "inliers", "covariance_rad2", "rms_arcsec")

    def __init__(self, solved, reason, C, inliers, covariance_rad2, rms_arcsec):
        self.solved, self.reason, self.C, self.inliers = solved, reason, C, inliers
        self.covariance_rad2, self.rms_arcsec = covariance_rad2, rms_arcsec


def _robust_attitude(u, v, sigma_rad, k_sigma: float, C_near) -> _Solution:
    """:func:`shipstar.attitude.solve_attitude`'s weighted solution with known per-star
    ``sigma_rad`` and outlier rejection, on its fast path.

    The same rule: QUEST with weights ``sigma^-2``; while the largest ratio of residual
    to ``k_sigma * sigma_i`` exceeds 1, that star is dropped and the attitude solved
    again; the covariance is Shuster's ``(sum sigma_i^-2 (I - w_i w_i^T))^-1`` about the
    sensor axes.  The vectors are unit and finite by construction, so solve_attitude's
    input checks (which cost more than the solve: ~0.25 ms for 40 stars, 0.5 ms for
    120) are not needed; the tests check that both give the same attitude and inliers.
    QUEST is solved relative to ``C_near`` (a rotation near the answer), which spares
    its sequential rotations.
    """
    from shipstar.attitude import quest_single

    a = 1.0 / (sigma_rad * sigma_rad)
    thr2 = (k_sigma * sigma_rad) ** 2
    active = np.ones(u.shape[0], bool)
    while True:
        ua, va = u[active], v[active]
        C = C_near @ quest_single(ua, va @ C_near, a[active])
        d = u @ C.T - v
        r2 = np.einsum("ij,ij->i", d, d)                     # chord^2 = angle^2 to 1e-12
        ratio = np.where(active, r2 / thr2, -np.inf)
        worst = int(np.argmax(ratio))
        if ratio[worst] <= 1.0:
            break
        if np.count_nonzero(active) <= 2:
            return _Solution(False, f"inconsistent stars: residual {math.sqrt(r2[worst]) / ASEC2RAD:.3g} arcsec "
                             f"exceeds {k_sigma:g} sigma with only 2 stars left", None, active, None, math.nan)
        active[worst] = False
        C_near = C
    aa = a[active]
    f_mat = aa.sum() * np.eye(3) - (ua * aa[:, None]).T @ ua
    try:
        cov = _inv3(f_mat)
    except ShipstarError:
        return _Solution(False, "degenerate geometry: the matched stars are all parallel", None, active, None,
                         math.nan)
    rms = math.sqrt(float(r2[active].mean())) / ASEC2RAD
    return _Solution(True, "", C, active, cov, rms)


def deep_match(stars, sigma_px, identification, catalog, *, epoch_jyear: float, camera=None,
               pixel_scale_arcsec: float | None = None, gate_sigma: float = 4.0,
               max_chance: float = 0.01, k_sigma: float = 5.0, max_sigma_px: float = 0.3) -> DeepMatch:
    """Name every detected star the deep catalog can, given a solved identification.

    Parameters
    ----------
    stars : array_like, (N, 2) or (N, 3)
        The stars the identification was run on, in the same order: pixel centroids
        ``xy_px`` (with ``camera``; the identification's focal scale and radial term are
        applied), or sensor-frame unit vectors (e.g. ``identification.u_sensor``).
    sigma_px : array_like, (N,)
        1-sigma centroid error per axis of each star, pixels (e.g. the extraction's
        ``xy_sigma_px`` with a floor; finite and > 0).
    identification : Identification
        A solved lost-in-space or tracking identification of ``stars``.
    catalog : StarCatalog
        The deep catalog (:func:`deep_catalog`); it must hold every identified star.
    epoch_jyear : float
        Epoch of the frame (Julian year) for the catalog's proper motions.
    camera : Camera, optional
        Needed for pixel centroids; gives the pixel scale.
    pixel_scale_arcsec : float, optional
        Pixel scale for unit-vector input without a camera.
    gate_sigma : float
        Pairing gate in units of each star's predicted-position error.
    max_chance : float
        Largest expected number of chance pairs per frame; the gates shrink to keep it.
    k_sigma : float
        Outlier threshold of the local fit and of ``solve_attitude``.
    max_sigma_px : float
        Detections with a larger ``sigma_px`` are not paired: failed fits and blends
        (the pipeline gives a NaN extraction sigma 1 px), whose wide gates would take
        most of the chance budget for a weight ~1/100 of a faint star's.

    Returns
    -------
    DeepMatch
        ``solved=False`` with a reason when the identification was not solved or the
        attitude could not be solved.

    Raises
    ------
    ShipstarError
        Bad shapes or options, missing camera / pixel scale, a catalog without the
        identified stars.
    """
    from shipstar.identify._result import Identification
    from shipstar.sky.catalog import StarCatalog

    t0 = time.perf_counter()
    if not isinstance(identification, Identification):
        raise ShipstarError(f"identification must be an Identification, got {type(identification).__name__}")
    if not isinstance(catalog, StarCatalog):
        raise ShipstarError(f"catalog must be a StarCatalog (see deep_catalog), got {type(catalog).__name__}")
    epoch, gate_sigma, max_chance, k_sigma = _check_options(epoch_jyear, gate_sigma, max_chance, k_sigma)
    max_sigma = _finite(max_sigma_px, "max_sigma_px")
    if max_sigma <= 0.0:
        raise ShipstarError(f"max_sigma_px must be > 0, got {max_sigma_px}")
    n = int(identification.hip.shape[0])
    t_m, u_m, scale = _measured(stars, n, camera, pixel_scale_arcsec, identification)
    sig_px = _sigma(sigma_px, n)
    sig_rad = sig_px * scale
    mode = identification.mode
    if not identification.solved:
        return _failed(n, mode, f"identification not solved: {identification.reason}", u_m, identification, t0)
    if np.count_nonzero(np.asarray(identification.hip) >= 0) < 2:
        return _failed(n, mode, "fewer than 2 identified stars to predict from", u_m, identification, t0)
    frame = _Frame(t_m, u_m, sig_rad, identification, catalog, _sky_index(catalog, epoch), epoch)
    frame.offered0 &= sig_px <= max_sigma
    return _run(frame, identification, gate_sigma, max_chance, k_sigma, t0)


def _run(frame: _Frame, idn, gate_sigma, max_chance, k_sigma, t0) -> DeepMatch:
    """Pair and solve; then once more with the solved attitude (module docstring).

    First round: predictions ``t + a + B t`` from the affine local model of the
    identified stars (their attitude's error included).  Second round: the solved
    attitude, which holds the rigid part, plus the model's non-rigid part ``S t``, with
    the first round's prediction variances (an upper bound: the solve used more stars);
    the attitude is solved again only if the pairs changed.  The second pairing is
    skipped when it cannot change anything: no prediction moved by the first round's
    margin and no added pair was rejected (which could lift the cap on the gates).
    """
    n = frame.t_m.shape[0]
    C = np.asarray(idn.C_icrs_from_sensor, float)
    local = frame.local_model(C, k_sigma)
    var = frame.variance(local)
    t_p = _project(frame.field_u, C)
    t_pred = t_p + local.predict_offset(t_p)
    last = None
    for _ in range(2):
        det, rows, v_new, n_amb, cap, chance, margin = frame.new_pairs(t_pred, var, gate_sigma, max_chance)
        if last is not None and det.tolist() == last[0] and rows.tolist() == last[1]:
            break
        sol, m, cat = frame.solve(det, rows, v_new, local, k_sigma, C)
        if not sol.solved:
            return _failed(n, idn.mode, f"attitude from the matched stars: {sol.reason}", frame.u_m, idn, t0)
        rejected = np.zeros(n, bool)
        rejected[m[~sol.inliers]] = True
        rejected[frame.ident] = False                            # identified stars keep their names
        frame.excluded |= rejected
        keep = ~rejected[det]
        last = (det[keep].tolist(), rows[keep].tolist(), sol, m, cat, n_amb, cap, chance)
        C = sol.C
        t_p = _project(frame.field_u, C)
        t_next = t_p + t_p @ local.nonrigid.T
        moved = t_next - t_pred
        if keep.all() and float(np.max(np.einsum("ij,ij->i", moved, moved), initial=0.0)) < margin * margin:
            break
        t_pred = t_next
    _, _, sol, m, cat, n_amb, cap, chance = last
    cat[frame.excluded] = -1
    inliers = np.zeros(n, bool)
    inliers[m[sol.inliers]] = True
    return _result(frame, idn, sol, cat, inliers, local, n_amb, cap, chance, t0)


def _result(frame, idn, sol, cat, inliers, local, n_amb, cap, chance, t0) -> DeepMatch:
    matched = cat >= 0
    added = matched.copy()
    added[frame.ident] = False
    hip = np.asarray(idn.hip, np.int64).copy()
    hip[added] = frame.catalog_hip[cat[added]]
    return DeepMatch(
        solved=True, reason="", mode=idn.mode, C_icrs_from_sensor=sol.C, hip=hip,
        catalog_index=cat, added=added, inliers=inliers, u_sensor=frame.u_m,
        n_identified=int(frame.ident.size), n_matched=int(np.count_nonzero(matched)),
        n_added=int(np.count_nonzero(added)), n_ambiguous=int(n_amb),
        n_rejected=int(np.count_nonzero(frame.excluded)), expected_chance=float(chance),
        gate_max_arcsec=float(cap) / ASEC2RAD, sigma_scale=math.sqrt(local.kappa2), nonrigid=local.nonrigid,
        covariance_rad2=sol.covariance_rad2, rms_arcsec=float(sol.rms_arcsec),
        focal_scale=float(idn.focal_scale), radial_k1=float(idn.radial_k1),
        time_s=time.perf_counter() - t0)
