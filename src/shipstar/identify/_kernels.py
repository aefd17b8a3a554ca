"""Checked entry to the compiled identification loops (:mod:`._ckernels`, plain C).

The C functions take raw buffers; this module makes every array the dtype, order and
size they expect (per database once: the converted arrays are cached with it) and
turns their plain results into arrays.
"""

from __future__ import annotations

import struct
import weakref

import numpy as np

from shipstar.identify import _ckernels
from shipstar.identify._verify import unit_f64

__all__ = ["db_buffers", "lis_solve", "lis_pinhole", "track_solve", "track_pinhole", "pack_track_params",
           "pack_camera", "wahba", "pinhole_unproject", "unit_rows", "size_quantum_rad", "SIZE_STEPS"]

_NO_ROWS = np.empty(0, dtype=np.int64)
_NO_MORE = np.empty((0, 2))
#: native float64 (the compiled entries read raw buffers; "y*" / "w*" refuse non-C-ordered ones)
_F64 = np.dtype(np.float64)
#: star-row dtypes of pattern_stars the compiled look-up reads as they are
_STAR_ROWS = (np.dtype(np.uint16), np.dtype(np.uint32))

#: scalar parameters travel as packed native int64 / float64 buffers
_pack_i11 = struct.Struct("=11q").pack
_pack_d16 = struct.Struct("=16d").pack
_pack_i4 = struct.Struct("=4q").pack
_pack_d9 = struct.Struct("=9d").pack
_pack_d4 = struct.Struct("=4d").pack

#: a pattern's largest edge is stored in steps of pattern_fov_rad / SIZE_STEPS (uint16:
#: 65535 steps hold edges up to 1.09 pattern_fov_rad; 0.5" steps for an 8.6 deg field).
#: The steps are kept in the database cache files (``_database._KERNEL_ARRAYS``) and
#: checked on load against this value: changing it needs ``_database._FILE_FORMAT``
#: raised, or every cached database would be refused as inconsistent.
SIZE_STEPS = 60000


def size_quantum_rad(params) -> float:
    """The step (rad) of the stored largest edges of a database with ``params``."""
    return float(params.pattern_fov_rad) / SIZE_STEPS


_BUFFERS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
#: ``[database, buffers]`` of the database used last (a session uses one or two)
_LAST: list = [None, None]


class _DbBuffers:
    """A database's arrays as the kernels read them."""

    __slots__ = ("u64", "u32", "pstars", "key_lo", "key_hi_start", "cell_start", "cell_index",
                 "cell_u", "size_q", "size_quantum_rad", "hip", "from_file", "uses",
                 "grid_n", "key_bits", "lo_bits", "bins", "n_patterns")

    def __init__(self, db):
        from shipstar.identify._database import kernel_arrays

        stored = kernel_arrays(db)     # (u64, cell_u, size_q) mapped from the cache file, or None
        self.u64 = np.ascontiguousarray(unit_f64(db) if stored is None else stored[0],
                                        dtype=np.float64)
        self.u32 = np.ascontiguousarray(db.u_icrs, dtype=np.float32)
        ps = db.pattern_stars          # uint16 (most databases) is read as it is stored
        self.pstars = np.ascontiguousarray(ps, dtype=ps.dtype if ps.dtype in _STAR_ROWS else np.uint32)
        self.key_lo = np.ascontiguousarray(db.key_lo, dtype=np.uint16)
        self.key_hi_start = np.ascontiguousarray(db.key_hi_start, dtype=np.int32)
        self.cell_start = np.ascontiguousarray(db.cell_start, dtype=np.int32)
        ci = db.cell_index             # uint16 (up to 65536 stars, as stored) is read as it is
        self.cell_index = np.ascontiguousarray(ci, dtype=ci.dtype if ci.dtype in _STAR_ROWS else np.uint32)
        self.hip = np.ascontiguousarray(db.hip, dtype=np.int32)
        n_cells = 6 * int(db.grid_n) ** 2
        if (self.u64.shape != (db.n_stars, 3) or self.pstars.shape != (db.n_patterns, 4)
                or self.key_lo.shape != (db.n_patterns,) or self.cell_start.shape != (n_cells + 1,)
                or self.key_hi_start.ndim != 1 or self.key_hi_start.shape[0] < 1
                or self.cell_index.ndim != 1 or self.cell_index.shape[0] != int(self.cell_start[-1])):
            raise ValueError("star database arrays are inconsistent")
        # one compiled pass: the offsets non-decreasing from 0 to the array ends, every
        # star row < n_stars, each key bucket sorted by key_lo (the compiled look-up reads
        # it so; the patterns are sorted by their whole key when the database is built),
        # then the star vectors of every cell in cell order (a prediction reads them in
        # sequence): cell_u = u64[cell_index], and each pattern's largest edge in steps of
        # size_quantum_rad (the look-up's first test, before it reads the pattern's stars),
        # made here or, stored, checked on a sample of rows (and the stored u64 against
        # u_icrs)
        m = self.cell_index.shape[0]
        self.size_quantum_rad = size_quantum_rad(db.params)
        made = stored is None or stored[1].shape != (m, 3) or stored[2].shape != (db.n_patterns,)
        self.from_file = not made               # cell_u and size_q as stored (checked), not made here
        self.cell_u = np.empty((m, 3)) if made else np.ascontiguousarray(stored[1], dtype=np.float64)
        self.size_q = (np.empty(db.n_patterns, dtype=np.uint16) if made
                       else np.ascontiguousarray(stored[2], dtype=np.uint16))
        rc = _ckernels.db_prepare(self.pstars, self.key_lo, self.key_hi_start, self.cell_start,
                                  self.cell_index, self.u64, self.cell_u, self.u32, self.size_q,
                                  self.size_quantum_rad, int(made))
        if rc == 2:
            raise ValueError("star database patterns are not sorted by key")
        if rc != 0:
            raise ValueError("star database arrays are inconsistent")
        self.grid_n, self.key_bits, self.lo_bits = int(db.grid_n), int(db.key_bits), int(db.lo_bits)
        self.bins, self.n_patterns = int(db.params.bins), int(db.n_patterns)
        self.uses = 0

    def used(self) -> None:
        """One more solve with this database: at the ``HUGE_PAGES_AFTER_USES``-th, its arrays
        move into huge pages (:func:`_into_huge_pages`)."""
        self.uses += 1
        if self.uses == HUGE_PAGES_AFTER_USES:
            _into_huge_pages(self, _HOT_ARRAYS)


#: A database's arrays move into huge pages at its this-many-th solve in a process: a
#: process that solves many frames (``measure``, ``live``, a benchmark's worker) gains, a
#: one-shot ``shipstar solve`` does not pay the copy (a blind solve's 2.3 million-pattern
#: database is ~35 MB: ~40-140 ms to copy, more than the solve itself).
HUGE_PAGES_AFTER_USES = 64
#: The kernels' arrays, in the order they are laid out (the key index first).
_HOT_ARRAYS = ("key_hi_start", "key_lo", "size_q", "pstars", "u32", "cell_start", "cell_index", "cell_u", "u64",
               "hip")


#: Huge page size (Linux, x86-64 and most others).
_HUGE_PAGE_BYTES = 2 * 2 ** 20


def _into_huge_pages(owner, names) -> None:
    """Copy ``owner``'s arrays ``names`` (read-only from then on) into one private anonymous
    mapping, 2 MB aligned and advised as transparent huge pages where the system offers
    them (Linux's ``madvise`` mode; nothing is changed where there is no private mapping).

    Why: the look-up's reads are random over a few MB (the key index, the patterns' stars,
    the cells' vectors). In 4 kB pages that is ~1,500 pages, more than the TLB keeps once
    other processes have run on the core: measured in bench_identify's interleaved runs
    (each solver in its own process), the lost-in-space kernel's median took 0.25-0.29 ms
    at 12 deg in 4 kB pages and 0.07 ms in huge pages, the same as run warm alone.  Done
    once a database is in use (:data:`HUGE_PAGES_AFTER_USES`), not at its first solve.
    """
    import mmap

    if not hasattr(mmap, "MAP_PRIVATE") or not hasattr(mmap, "MAP_ANONYMOUS"):
        return
    arrays = [getattr(owner, n) for n in names]
    offsets, total = [], 0
    for a in arrays:
        offsets.append(total)
        total += -(-a.nbytes // 64) * 64
    region = mmap.mmap(-1, total + _HUGE_PAGE_BYTES, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS)
    raw = np.frombuffer(region, dtype=np.uint8)
    shift = (-raw.ctypes.data) % _HUGE_PAGE_BYTES
    if hasattr(mmap, "MADV_HUGEPAGE"):
        try:
            region.madvise(mmap.MADV_HUGEPAGE, shift, -(-total // _HUGE_PAGE_BYTES) * _HUGE_PAGE_BYTES)
        except OSError:
            pass
    for n, a, off in zip(names, arrays, offsets):
        view = raw[shift + off:shift + off + a.nbytes].view(a.dtype).reshape(a.shape)
        view[...] = a
        view.setflags(write=False)
        setattr(owner, n, view)


def db_buffers(db) -> _DbBuffers:
    """The kernels' view of a database (made once per database; each call counts as a
    use, :meth:`_DbBuffers.used`)."""
    if _LAST[0] is db:
        buf = _LAST[1]
    else:
        buf = _BUFFERS.get(db)
        if buf is None:
            buf = _BUFFERS[db] = _DbBuffers(db)
        _LAST[:] = [db, buf]
    buf.used()
    return buf


def _f64(a, cols: int) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != cols:
        raise ValueError(f"expected an (N, {cols}) array, got {a.shape}")
    return a


_CHECKED: dict = {}


def _check_combos(combos, ends, k: int) -> None:
    """Pattern rows must be int64 (C, 4) with stars < k, ``ends`` int64 rows <= C
    (checked once per pair of arrays: they come from lru caches)."""
    key = (id(combos), id(ends), k)
    if _CHECKED.get(key) == (combos, ends):
        return
    ok = (isinstance(combos, np.ndarray) and combos.dtype == np.int64 and combos.ndim == 2
          and combos.shape[1] == 4 and combos.flags.c_contiguous
          and isinstance(ends, np.ndarray) and ends.dtype == np.int64 and ends.ndim == 1
          and (combos.size == 0 or 0 <= int(combos.min()) and int(combos.max()) < k)
          and (ends.size == 0 or 0 <= int(ends.min()) and int(ends.max()) <= combos.shape[0]))
    if not ok:
        raise ValueError("bad pattern combinations")
    if len(_CHECKED) > 64:
        _CHECKED.clear()
    _CHECKED[key] = (combos, ends)


def _usable(usable) -> np.ndarray:
    return _NO_ROWS if usable is None else np.ascontiguousarray(usable, dtype=np.int64)


def lis_params(b: "_DbBuffers", k: int, m: int, params):
    """The packed ``(iparams, dparams)`` of the compiled search; ``params = (min_matches,
    max_candidates, fit, fit_radial, e_edge, max_edge, min_edge, model_tol, ftol,
    error_rad, half_diag, gate_fine, area0, p_false_max, max_time_s, bounds (y0, y1, z0,
    z1))``."""
    (min_matches, max_candidates, fit, fit_radial, e_edge, max_edge, min_edge, model_tol, ftol,
     error_rad, half_diag, gate_fine, area0, p_false_max, max_time_s, bounds) = params
    ip = _pack_i11(k, b.grid_n, b.key_bits, b.lo_bits, b.bins, b.n_patterns, min_matches,
                   max_candidates, int(fit), int(fit_radial), m)
    y0, y1, z0, z1 = bounds
    dp = _pack_d16(e_edge, max_edge, min_edge, model_tol, ftol, error_rad, half_diag, gate_fine,
                   area0, p_false_max, max_time_s, y0, y1, z0, z1, b.size_quantum_rad)
    return ip, dp


def lis_solve(t, u0, k: int, combos, ends, db, params, *, n_field: int, usable, t_more=None):
    """The lost-in-space search over the usable stars ``t (n, 2)``, ``u0 (n, 3)``.

    ``combos (C, 4)`` are the 4-star patterns of the brightest ``k`` stars in search
    order and ``ends`` the end rows of their batches; ``usable`` the input rows of the
    ``n`` stars (None: rows ``0 .. n - 1``) of the ``n_field`` input stars; ``params``
    the gates and limits (:func:`lis_params`, from :func:`._lost_in_space.search_params`);
    ``t_more (n_more, 2)`` the usable stars beyond the ``n`` (fainter: a pair whose catalog
    star has one of them nearer than its own star is not matched).  Returns
    ``(status, C (3, 3), star_index (n_field,), hip (n_field,), n_matched, n_verified,
    n_patterns, s, k1, p_false, rms_arcsec)``; status 1: solved, 0: no candidate
    verified, 2: stopped by ``max_time_s`` / ``max_candidates``.
    """
    t = _f64(t, 2)
    u0 = _f64(u0, 3)
    n = t.shape[0]
    if u0.shape[0] != n or not 4 <= k <= min(n, 32) or n > n_field:
        raise ValueError("bad lost-in-space input sizes")
    _check_combos(combos, ends, k)
    t_more = _NO_MORE if t_more is None else _f64(t_more, 2)
    b = db_buffers(db)
    ip, dp = lis_params(b, k, n, params)
    C = np.empty((3, 3))
    star = np.empty(n_field, dtype=np.int64)
    hip = np.empty(n_field, dtype=np.int64)
    status, m, n_verified, n_patterns, s, k1, p_false, rms = _ckernels.lis_solve(
        t, u0, t_more, combos, ends, b.u64, b.u32, b.pstars, b.key_lo, b.key_hi_start, b.cell_start,
        b.cell_index, b.cell_u, b.size_q, ip, dp, C, _usable(usable), b.hip, star, hip)
    return status, C, star, hip, m, n_verified, n_patterns, s, k1, p_false, rms


def lis_pinhole(xy, cam, m: int, k: int, combos, ends, db, params):
    """:func:`lis_solve` from pixel centroids ``xy (N, 2)`` (float64, C order) of a camera
    without distortion, ``cam = (x0_px, y0_px, pixel_mm, f_mm)``, in one compiled call
    (the unprojection of :func:`pinhole_unproject` included); the brightest ``m`` rows
    are the usable stars.  Returns None when a centroid is not finite, else
    ``(status, C, star_index, hip, u_sensor (N, 3), n_matched, n_verified, n_patterns,
    s, k1, p_false, rms_arcsec)`` with ``u_sensor`` at the solved ``s`` and ``k1``."""
    n = xy.shape[0]
    if xy.dtype is not _F64 or xy.shape != (n, 2) or not 4 <= k <= min(m, 32) or m > n:
        raise ValueError("bad lost-in-space input sizes")
    _check_combos(combos, ends, k)
    b = db_buffers(db)
    ip, dp = lis_params(b, k, m, params)
    C = np.empty((3, 3))
    u = np.empty((n, 3))
    star = np.empty(n, dtype=np.int64)
    hip = np.empty(n, dtype=np.int64)
    out = _ckernels.lis_pinhole(
        xy, _pack_d4(*cam), combos, ends, b.u64, b.u32, b.pstars, b.key_lo, b.key_hi_start,
        b.cell_start, b.cell_index, b.cell_u, b.size_q, ip, dp, C, u, b.hip, star, hip)
    if out is None:
        return None
    status, n_match, n_verified, n_patterns, s, k1, p_false, rms = out
    return status, C, star, hip, u, n_match, n_verified, n_patterns, s, k1, p_false, rms


def _track_params(b: "_DbBuffers", m: int, params):
    min_matches, n_trials, (cy, cz, hy, hz), gate, gate_prior, gate_shift, area, limit = params
    return (_pack_i4(b.grid_n, min_matches, n_trials, m),
            _pack_d9(cy, cz, hy, hz, gate, gate_prior, gate_shift, area, limit))


def _rotation_arg(C_prior) -> np.ndarray:
    """``C_prior`` (3, 3) as the C kernels read it (float64, C order)."""
    C = np.ascontiguousarray(C_prior, dtype=np.float64)
    if C.shape != (3, 3):
        raise ValueError("C_prior must be (3, 3)")
    return C


def track_solve(t, w, C_prior, db, params, *, n_field: int, usable, t_more=None):
    """Tracking of the stars ``t (n, 2)`` (tangent plane at the focal scale), ``w (n, 3)``
    (their unit vectors; input rows ``usable``, None: ``0 .. n - 1``, of ``n_field``)
    from ``C_prior (3, 3)``; ``params`` the gates (:func:`._tracking.track_params`).
    ``t_more (n_more, 2)``: the detections beyond the used ones (fainter; a pair whose
    catalog star has one of them nearer than its own detection is not matched).
    Returns ``(code, count, p, voted, C (3, 3), star_index (n_field,), hip (n_field,),
    n_matched, p_false, rms_arcsec)``: code 0 solved, else the reason (see
    :mod:`._tracking`) with its count / chance probability."""
    t = _f64(t, 2)
    w = _f64(w, 3)
    n = t.shape[0]
    if w.shape[0] != n or n > 64 or n > n_field:
        raise ValueError("bad tracking input sizes")
    t_more = _NO_MORE if t_more is None else _f64(t_more, 2)
    C_prior = _rotation_arg(C_prior)
    b = db_buffers(db)
    ip, dp = _track_params(b, n, params)
    C = np.empty((3, 3))
    star = np.empty(n_field, dtype=np.int64)
    hip = np.empty(n_field, dtype=np.int64)
    code, count, p, voted, m, p_false, rms, _ = _ckernels.track_solve(
        t, w, t_more, C_prior, b.cell_u, b.cell_start, b.cell_index, ip, dp, C, _usable(usable),
        b.hip, star, hip)
    return code, count, p, bool(voted), C, star, hip, m, p_false, rms


def pack_track_params(db, m: int, params) -> tuple:
    """``(iparams, dparams)``: :func:`._tracking.track_params` packed for
    :func:`track_pinhole` with ``m`` used rows."""
    return _track_params(db_buffers(db), m, params)


def pack_camera(cam) -> bytes:
    """``cam = (x0_px, y0_px, pixel_mm, f_mm)`` packed for the pinhole kernels."""
    return _pack_d4(*cam)


def track_pinhole(xy, cam, m: int, C_prior, db, iparams, dparams):
    """:func:`track_solve` from pixel centroids ``xy (N, 2)`` (float64, C order) of a
    camera without distortion, ``cam = (x0_px, y0_px, pixel_mm, f_mm)`` (or
    :func:`pack_camera` of it), at focal scale 1, in one compiled call; the brightest
    ``m`` (<= 64) rows are used (the others as ``t_more``); ``iparams, dparams`` from
    :func:`pack_track_params` for this ``m``.  Returns None when a centroid is not
    finite, else ``(code, count, p, voted, C, star_index, hip, u_sensor (N, 3),
    n_matched, p_false, rms_arcsec)``."""
    n = xy.shape[0]
    if xy.dtype is not _F64 or xy.shape != (n, 2) or m > min(n, 64):   # C order: the buffer's
        raise ValueError("bad tracking input sizes")
    C_prior = _rotation_arg(C_prior)
    b = db_buffers(db)
    C = np.empty((3, 3))
    u = np.empty((n, 3))
    star = np.empty(n, dtype=np.int64)
    hip = np.empty(n, dtype=np.int64)
    out = _ckernels.track_pinhole(xy, cam if isinstance(cam, bytes) else _pack_d4(*cam), C_prior,
                                  b.cell_u, b.cell_start, b.cell_index, iparams, dparams, C, u, b.hip,
                                  star, hip)
    if out is None:
        return None
    code, count, p, voted, n_match, p_false, rms, _ = out
    return code, count, p, bool(voted), C, star, hip, u, n_match, p_false, rms


def pinhole_unproject(xy, x0_px: float, y0_px: float, pixel_mm: float, f_mm: float):
    """``(u (N, 3), t (N, 2), all_finite)``: :meth:`Camera.unproject` of a camera without
    distortion and the tangent-plane coordinates ``u[:, 1:] / u[:, :1]``."""
    xy = _f64(xy, 2)
    u = np.empty((xy.shape[0], 3))
    t = np.empty((xy.shape[0], 2))
    finite = _ckernels.pinhole_unproject(xy, _pack_d4(x0_px, y0_px, pixel_mm, f_mm), u, t)
    return u, t, finite


def unit_rows(t, scale: float, k1: float) -> np.ndarray:
    """:meth:`StarField.unit` ``(N, 3)`` of every row of ``t (N, 2)``."""
    t = _f64(t, 2)
    out = np.empty((t.shape[0], 3))
    _ckernels.unit_rows(t, float(scale), float(k1), out)
    return out


def wahba(w_body, v_ref) -> np.ndarray:
    """The compiled QUEST: ``C_ref_from_body`` for matched unit vectors ``(k, 3)``."""
    w = _f64(w_body, 3)
    v = _f64(v_ref, 3)
    if w.shape != v.shape or w.shape[0] == 0:
        raise ValueError("w_body and v_ref must be of one shape (k, 3), k >= 1")
    C = np.empty((3, 3))
    _ckernels.wahba(w, v, C)
    return C
