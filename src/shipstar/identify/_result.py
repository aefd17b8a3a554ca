"""Result of a star identification."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shipstar.frames import ra_dec_roll_from_C_icrs_from_sensor
from shipstar.units import RAD2DEG

__all__ = ["Identification", "failed_identification", "make_identification"]



def ra_dec_roll_deg(solved: bool, C_icrs_from_sensor) -> tuple[float, float, float]:
    """Boresight RA, Dec and roll in degrees of a solution (NaN when not solved)."""
    if not solved:
        return (float("nan"),) * 3
    ra, dec, roll = ra_dec_roll_from_C_icrs_from_sensor(C_icrs_from_sensor)
    return float(ra * RAD2DEG), float(dec * RAD2DEG), float(roll * RAD2DEG)

@dataclass(frozen=True, eq=False)
class Identification:
    """Which catalog star each measured star is, and the attitude they give.

    Attributes
    ----------
    solved : bool
        True only if the match was verified and its chance probability ``p_false`` is
        below the requested bound.
    reason : str
        Why not solved ("" when solved).
    mode : str
        ``"lost_in_space"`` or ``"tracking"``.
    C_icrs_from_sensor : ndarray (3, 3)
        Attitude (QUEST over all matched stars); NaN when not solved.
    star_index : ndarray (N,), int
        Database row of each input star, -1 if unmatched (or not solved).
    hip : ndarray (N,), int
        HIP number of each input star, -1 if unmatched.
    u_sensor : ndarray (N, 3)
        Sensor-frame unit vectors of the input stars at the solved focal scale (NaN rows
        for non-finite input).
    n_matched : int
    p_false : float
        Upper bound on the probability that a match this good is chance (1 when not
        solved): binomial tail of the chance matches, times the number of candidates
        verified.
    rms_arcsec : float
        RMS angle between matched measured and catalog directions after the fit (NaN if
        not solved).
    focal_scale : float
        ``f_nominal / f_solved`` (1 for a known camera).
    radial_k1 : float
        Fitted radial term ``k1`` of ``t_true = s t (1 + k1 |t|^2)`` (tangent-plane
        units; 0 unless the focal length was uncertain).
    n_patterns : int
        Image 4-star patterns looked up (lost-in-space).
    n_candidates : int
        Catalog patterns (or priors) verified.
    time_s : float
        Wall time of the identification.
    """

    solved: bool
    reason: str
    mode: str
    C_icrs_from_sensor: np.ndarray
    star_index: np.ndarray
    hip: np.ndarray
    u_sensor: np.ndarray
    n_matched: int
    p_false: float
    rms_arcsec: float
    focal_scale: float
    radial_k1: float
    n_patterns: int
    n_candidates: int
    time_s: float

    @property
    def ra_dec_roll_deg(self) -> tuple[float, float, float]:
        """Boresight RA, Dec and roll (docs/conventions.md) in degrees (NaN if not solved)."""
        return ra_dec_roll_deg(self.solved, self.C_icrs_from_sensor)


_FIELDS = tuple(Identification.__dataclass_fields__)


def make_identification(*values) -> Identification:
    """``Identification(*values)`` (the fields in their order) without the frozen
    dataclass ``__init__``'s one ``object.__setattr__`` per field: every tracked frame
    builds one."""
    obj = object.__new__(Identification)
    obj.__dict__.update(zip(_FIELDS, values))
    return obj


def failed_identification(n: int, mode: str, reason: str, *, n_patterns: int = 0,
                          n_candidates: int = 0, time_s: float = 0.0) -> Identification:
    """An unsolved :class:`Identification` for ``n`` input stars."""
    return Identification(
        solved=False, reason=reason, mode=mode, C_icrs_from_sensor=np.full((3, 3), np.nan),
        star_index=np.full(n, -1, dtype=np.int64), hip=np.full(n, -1, dtype=np.int64),
        u_sensor=np.full((n, 3), np.nan), n_matched=0, p_false=1.0, rms_arcsec=float("nan"),
        focal_scale=1.0, radial_k1=0.0, n_patterns=n_patterns, n_candidates=n_candidates, time_s=time_s,
    )
