"""Frames, rotations and angle conventions (see ``docs/conventions.md``).

Every matrix here is named for what it maps: ``C_hor_from_deck @ v_deck`` gives
``v_hor``.  All angles are radians.  Every function is vectorised: scalar angles give a
``(3, 3)`` matrix, angle arrays of shape ``S`` give ``S + (3, 3)``; vectors are ``(..., 3)``.

Frames (all right-handed):

``hor``
    Local astronomical horizontal frame (the seeds' INS horizontal frame "DP"):
    X north, Y up (along the plumb line), Z east.
``deck``
    Ship deck frame: X to the bow, Y up normal to the deck, Z to starboard.
``sensor``
    Star sensor image-space frame: X along the boresight (out of the lens into the
    sky), Y up in the image (toward decreasing row ``y_px``), Z to the right in the
    image (toward increasing column ``x_px``).
``icrs``
    Celestial reference frame (J2000 / ICRS): X to the equinox, Z to the pole.

Elementary rotations are the seeds' *coordinate-axis* (passive) rotations; seed 001
eq. 2 only comes out with these.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "rot_x", "rot_y", "rot_z",
    "C_hor_from_deck", "ship_angles_from_C_hor_from_deck",
    "C_deck_from_sensor", "installation_angles_from_C_deck_from_sensor",
    "gimbal_lock_mask", "rotation_vectors_rad",
    "unit_from_az_el", "az_el_from_unit",
    "unit_from_ra_dec", "ra_dec_from_unit",
    "C_icrs_from_sensor", "ra_dec_roll_from_C_icrs_from_sensor",
    "q_wxyz_from_matrix", "matrix_from_q_wxyz", "q_wxyz_multiply",
    "rotation_angle_rad", "orthonormalize", "wrap_2pi", "wrap_pi",
]

TWO_PI = 2.0 * np.pi

#: |cos(middle angle)| below which a Y-Z-X angle set is treated as gimbal locked.
GIMBAL_COS_TOL = 1e-9


def _trig(angle_rad):
    a = np.asarray(angle_rad, dtype=float)
    return a, np.cos(a), np.sin(a)


def rot_x(angle_rad):
    """Passive rotation of the coordinate axes about X by ``angle_rad``.

    ``[[1, 0, 0], [0, c, s], [0, -s, c]]``; shape ``S + (3, 3)`` for angles of shape ``S``.
    """
    a, c, s = _trig(angle_rad)
    out = np.zeros(a.shape + (3, 3))
    out[..., 0, 0] = 1.0
    out[..., 1, 1] = c
    out[..., 1, 2] = s
    out[..., 2, 1] = -s
    out[..., 2, 2] = c
    return out


def rot_y(angle_rad):
    """Passive rotation about Y: ``[[c, 0, -s], [0, 1, 0], [s, 0, c]]``."""
    a, c, s = _trig(angle_rad)
    out = np.zeros(a.shape + (3, 3))
    out[..., 0, 0] = c
    out[..., 0, 2] = -s
    out[..., 1, 1] = 1.0
    out[..., 2, 0] = s
    out[..., 2, 2] = c
    return out


def rot_z(angle_rad):
    """Passive rotation about Z: ``[[c, s, 0], [-s, c, 0], [0, 0, 1]]``."""
    a, c, s = _trig(angle_rad)
    out = np.zeros(a.shape + (3, 3))
    out[..., 0, 0] = c
    out[..., 0, 1] = s
    out[..., 1, 0] = -s
    out[..., 1, 1] = c
    out[..., 2, 2] = 1.0
    return out


def _yzx(a_rad, b_rad, c_rad):
    """``R_y(a) @ R_z(-b) @ R_x(-c)``, the structure shared by ship and installation."""
    return rot_y(a_rad) @ rot_z(-np.asarray(b_rad, float)) @ rot_x(-np.asarray(c_rad, float))


def _yzx_angles(C):
    """Invert :func:`_yzx`: returns ``(a in [0, 2pi), b in [-pi/2, pi/2], c in (-pi, pi])``.

    At gimbal lock (``|cos b| < GIMBAL_COS_TOL``) only ``a -/+ c`` is defined; ``c`` is
    set to 0 and ``a`` carries the whole rotation.
    """
    C = np.asarray(C, dtype=float)
    if C.shape == (3, 3):
        return _yzx_angles_one(C)
    b = np.arctan2(C[..., 1, 0], np.hypot(C[..., 1, 1], C[..., 1, 2]))
    a = np.arctan2(C[..., 2, 0], C[..., 0, 0])
    c = -np.arctan2(C[..., 1, 2], C[..., 1, 1])
    locked = np.hypot(C[..., 0, 0], C[..., 2, 0]) < GIMBAL_COS_TOL
    if locked.any():
        a_locked = np.arctan2(-C[..., 0, 2], C[..., 2, 2])
        a = np.where(locked, a_locked, a)
        c = np.where(locked, 0.0, c)
    return wrap_2pi(a), b, c


def _yzx_angles_one(C):
    """:func:`_yzx_angles` of one (3, 3) matrix in plain floats (the fusion asks for
    several every epoch; the array path costs ten times as much for one): the same
    operations in the same order, returned as NumPy floats."""
    (c00, _, c02), (c10, c11, c12), (c20, _, c22) = C.tolist()
    b = math.atan2(c10, math.hypot(c11, c12))
    if math.hypot(c00, c20) < GIMBAL_COS_TOL:
        a, c = math.atan2(-c02, c22), 0.0
    else:
        a, c = math.atan2(c20, c00), -math.atan2(c12, c11)
    a %= TWO_PI
    if a >= TWO_PI:
        a = 0.0
    return np.float64(a), np.float64(b), np.float64(c)


def C_hor_from_deck(heading_rad, pitch_rad, roll_rad):
    """Ship attitude matrix ``R_y(K) R_z(-psi) R_x(-theta)`` (seed 001 eq. 2).

    Parameters
    ----------
    heading_rad : array_like, shape S
        Heading K of the bow, from north toward east.
    pitch_rad : array_like, shape S
        Pitch psi, positive bow up.
    roll_rad : array_like, shape S
        Roll theta, positive starboard side down.

    Returns
    -------
    ndarray, shape S + (3, 3)
        Maps deck-frame vectors to horizontal-frame vectors.  Its first column is the bow
        direction ``[cos K cos psi, sin psi, sin K cos psi]``.
    """
    return _yzx(heading_rad, pitch_rad, roll_rad)


def ship_angles_from_C_hor_from_deck(C_hor_from_deck_):
    """Heading, pitch, roll (rad) from ``C_hor_from_deck`` (seed 003 eq. 15-17).

    ``K = atan2(C[2,0], C[0,0])`` in [0, 2pi), ``psi = asin(C[1,0])``,
    ``theta = -atan2(C[1,2], C[1,1])`` (seed 000 eq. 18 drops this minus sign).
    At pitch +-90 deg roll is set to 0 (see :func:`gimbal_lock_mask`).
    """
    return _yzx_angles(C_hor_from_deck_)


def C_deck_from_sensor(az_rad, el_rad, roll_rad):
    """Installation matrix ``R_y(A) R_z(-E) R_x(-gamma)`` (seed 000 eq. 2).

    Maps sensor-frame vectors to deck-frame vectors.  Its first column is the boresight
    in the deck frame: azimuth A from the bow toward starboard, elevation E above the
    deck; gamma is the roll of the sensor about its boresight (positive turns the image
    "right" axis, +Z, downward).  Seed 001 eq. 4 uses the transpose under the same name.
    """
    return _yzx(az_rad, el_rad, roll_rad)


def installation_angles_from_C_deck_from_sensor(C_deck_from_sensor_):
    """Installation azimuth, elevation, roll (rad) from ``C_deck_from_sensor``."""
    return _yzx_angles(C_deck_from_sensor_)


def gimbal_lock_mask(C, cos_tol=1e-6):
    """True where the middle (pitch/elevation) angle of a Y-Z-X matrix is within
    ``acos``-distance of +-90 deg, i.e. ``cos(pitch) < cos_tol``; shape ``S``."""
    C = np.asarray(C, dtype=float)
    if C.shape == (3, 3):
        return np.bool_(math.hypot(float(C[0, 0]), float(C[2, 0])) < cos_tol)
    return np.hypot(C[..., 0, 0], C[..., 2, 0]) < cos_tol


def unit_from_az_el(az_rad, el_rad):
    """Horizontal-frame unit vectors ``[cos E cos A, sin E, cos E sin A]``; shape S + (3,).

    Azimuth from north toward east, elevation above the horizon.  The same formula gives
    deck-frame vectors from (azimuth from bow toward starboard, elevation above deck).
    """
    az = np.asarray(az_rad, float)
    el = np.asarray(el_rad, float)
    ce = np.cos(el)
    return np.stack(np.broadcast_arrays(ce * np.cos(az), np.sin(el), ce * np.sin(az)), axis=-1)


def az_el_from_unit(v_hor):
    """Azimuth in [0, 2pi) and elevation (rad) of horizontal-frame vectors ``(..., 3)``."""
    v = np.asarray(v_hor, float)
    az = wrap_2pi(np.arctan2(v[..., 2], v[..., 0]))
    el = np.arctan2(v[..., 1], np.hypot(v[..., 0], v[..., 2]))
    return az, el


def unit_from_ra_dec(ra_rad, dec_rad):
    """ICRS unit vectors ``[cos d cos a, cos d sin a, sin d]``; shape S + (3,)."""
    ra = np.asarray(ra_rad, float)
    dec = np.asarray(dec_rad, float)
    cd = np.cos(dec)
    return np.stack(np.broadcast_arrays(cd * np.cos(ra), cd * np.sin(ra), np.sin(dec)), axis=-1)


def ra_dec_from_unit(v_icrs):
    """Right ascension in [0, 2pi) and declination (rad) of vectors ``(..., 3)``."""
    v = np.asarray(v_icrs, float)
    ra = wrap_2pi(np.arctan2(v[..., 1], v[..., 0]))
    dec = np.arctan2(v[..., 2], np.hypot(v[..., 0], v[..., 1]))
    return ra, dec


def _north_east_at(b):
    """Unit vectors toward celestial north and east at direction ``b`` (..., 3).

    At the poles (where they are undefined) north is taken along the RA = 0 meridian
    direction continued over the pole, so the result stays finite and orthonormal.
    """
    z = np.array([0.0, 0.0, 1.0])
    east = np.cross(z, b)
    n_e = np.linalg.norm(east, axis=-1, keepdims=True)
    pole = n_e[..., 0] < 1e-12
    if pole.any():
        east = np.where(pole[..., None], np.array([0.0, 1.0, 0.0]), east)
        n_e = np.where(pole[..., None], 1.0, n_e)
    east = east / n_e
    north = np.cross(b, east)
    return north, east


def C_icrs_from_sensor(ra_rad, dec_rad, roll_rad):
    """Sensor attitude in ICRS from boresight (ra, dec) and roll.

    Columns are the sensor axes in ICRS: X = boresight at (ra, dec); Y (image up) makes
    the position angle ``roll`` with celestial north, measured from north through east;
    Z (image right) = X cross Y.  With roll = 0, north is up and east is to the *left*
    (the sky seen from inside the sphere).  Shape ``S + (3, 3)``.
    """
    b = unit_from_ra_dec(ra_rad, dec_rad)
    north, east = _north_east_at(b)
    r = np.asarray(roll_rad, float)[..., None]
    y = np.cos(r) * north + np.sin(r) * east
    z = np.cross(b, y)
    return np.stack([b, y, z], axis=-1)


def ra_dec_roll_from_C_icrs_from_sensor(C_icrs_from_sensor_):
    """Invert :func:`C_icrs_from_sensor`: ``(ra in [0, 2pi), dec, roll in [0, 2pi))``."""
    C = np.asarray(C_icrs_from_sensor_, float)
    b = C[..., :, 0]
    y = C[..., :, 1]
    ra, dec = ra_dec_from_unit(b)
    north, east = _north_east_at(b)
    roll = wrap_2pi(np.arctan2(np.sum(y * east, -1), np.sum(y * north, -1)))
    return ra, dec, roll


# --------------------------------------------------------------------------------------
# Quaternions: scalar first (q_wxyz), Hamilton product, and q_a_from_b represents the
# same rotation as C_a_from_b:  v_a = q (x) v_b (x) q*  ==  C_a_from_b @ v_b.
# The canonical sign has w >= 0.
# --------------------------------------------------------------------------------------

def matrix_from_q_wxyz(q_wxyz):
    """Rotation matrix ``(..., 3, 3)`` from quaternions ``(..., 4)`` (normalised first)."""
    q = np.asarray(q_wxyz, float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty(q.shape[:-1] + (3, 3))
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - w * z)
    out[..., 0, 2] = 2 * (x * z + w * y)
    out[..., 1, 0] = 2 * (x * y + w * z)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - w * x)
    out[..., 2, 0] = 2 * (x * z - w * y)
    out[..., 2, 1] = 2 * (y * z + w * x)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def q_wxyz_from_matrix(C):
    """Quaternion ``(..., 4)``, scalar first with w >= 0, from rotation matrices ``(..., 3, 3)``.

    Shepperd's method: the largest of the four candidates is used, so it is accurate for
    every rotation, including 180 deg.
    """
    C = np.asarray(C, float)
    if C.shape == (3, 3):
        return _q_wxyz_one(C)
    tr = C[..., 0, 0] + C[..., 1, 1] + C[..., 2, 2]
    cand = np.stack([tr, C[..., 0, 0], C[..., 1, 1], C[..., 2, 2]], axis=-1)
    k = np.argmax(cand, axis=-1)
    q = np.empty(C.shape[:-2] + (4,))
    # case w largest
    w4 = np.stack([1 + tr, C[..., 2, 1] - C[..., 1, 2], C[..., 0, 2] - C[..., 2, 0],
                   C[..., 1, 0] - C[..., 0, 1]], -1)
    x4 = np.stack([C[..., 2, 1] - C[..., 1, 2], 1 + 2 * C[..., 0, 0] - tr,
                   C[..., 0, 1] + C[..., 1, 0], C[..., 0, 2] + C[..., 2, 0]], -1)
    y4 = np.stack([C[..., 0, 2] - C[..., 2, 0], C[..., 0, 1] + C[..., 1, 0],
                   1 + 2 * C[..., 1, 1] - tr, C[..., 1, 2] + C[..., 2, 1]], -1)
    z4 = np.stack([C[..., 1, 0] - C[..., 0, 1], C[..., 0, 2] + C[..., 2, 0],
                   C[..., 1, 2] + C[..., 2, 1], 1 + 2 * C[..., 2, 2] - tr], -1)
    q = np.where((k == 0)[..., None], w4,
                 np.where((k == 1)[..., None], x4, np.where((k == 2)[..., None], y4, z4)))
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where((q[..., :1] < 0), -q, q)


def _q_wxyz_one(C):
    """Shepperd's method for one matrix in Python floats (~10x faster than the array path)."""
    (c00, c01, c02), (c10, c11, c12), (c20, c21, c22) = C.tolist()
    tr = c00 + c11 + c22
    k = max(range(4), key=(tr, c00, c11, c22).__getitem__)
    if k == 0:
        q = (1.0 + tr, c21 - c12, c02 - c20, c10 - c01)
    elif k == 1:
        q = (c21 - c12, 1.0 + 2.0 * c00 - tr, c01 + c10, c02 + c20)
    elif k == 2:
        q = (c02 - c20, c01 + c10, 1.0 + 2.0 * c11 - tr, c12 + c21)
    else:
        q = (c10 - c01, c02 + c20, c12 + c21, 1.0 + 2.0 * c22 - tr)
    n = math.sqrt(sum(x * x for x in q)) * (1.0 if q[0] >= 0 else -1.0)
    return np.array([x / n for x in q])


def q_wxyz_multiply(p_wxyz, q_wxyz):
    """Hamilton product ``p (x) q``; ``matrix(p (x) q) == matrix(p) @ matrix(q)``."""
    p = np.asarray(p_wxyz, float)
    q = np.asarray(q_wxyz, float)
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack([
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    ], axis=-1)


def rotation_angle_rad(C):
    """Rotation angle (rad, in [0, pi]) of rotation matrices ``(..., 3, 3)``.

    Use ``rotation_angle_rad(C_est.T @ C_true)`` for the total attitude error.  Computed
    from the skew part and the trace with ``atan2``, so it is accurate for tiny angles.
    """
    C = np.asarray(C, float)
    tr = C[..., 0, 0] + C[..., 1, 1] + C[..., 2, 2]
    s = np.stack([C[..., 2, 1] - C[..., 1, 2], C[..., 0, 2] - C[..., 2, 0],
                  C[..., 1, 0] - C[..., 0, 1]], -1)
    return np.arctan2(0.5 * np.linalg.norm(s, axis=-1), 0.5 * (tr - 1.0))


def rotation_vectors_rad(C) -> np.ndarray:
    """Rotation vectors (rad) ``phi`` with ``C = exp([phi x])``, shape ``(N, 3)``, of rotation
    matrices ``(N, 3, 3)`` (or one (3, 3)) whose angles are below pi."""
    C = np.asarray(C, float).reshape(-1, 3, 3)
    s = np.stack([C[:, 2, 1] - C[:, 1, 2], C[:, 0, 2] - C[:, 2, 0], C[:, 1, 0] - C[:, 0, 1]], axis=1)
    n = np.sqrt(np.einsum("ij,ij->i", s, s))
    angle = np.arctan2(0.5 * n, 0.5 * (C[:, 0, 0] + C[:, 1, 1] + C[:, 2, 2] - 1.0))
    scale = np.divide(angle, n, out=np.full_like(n, 0.5), where=n > 0.0)      # angle / (2 sin angle) * 2
    return s * scale[:, None]


def orthonormalize(C):
    """Nearest rotation matrix (polar decomposition by SVD) to each ``(..., 3, 3)``."""
    u, _, vt = np.linalg.svd(np.asarray(C, float))
    d = np.sign(np.linalg.det(u @ vt))
    u = u * np.concatenate([np.ones(d.shape + (2,)), d[..., None]], -1)[..., None, :]
    return u @ vt


def wrap_2pi(angle_rad):
    """Angle(s) wrapped into [0, 2pi)."""
    a = np.mod(np.asarray(angle_rad, float), TWO_PI)
    return np.where(a >= TWO_PI, 0.0, a)


def wrap_pi(angle_rad):
    """Angle(s) wrapped into (-pi, pi]."""
    a = np.asarray(angle_rad, float)
    return np.pi - np.mod(np.pi - a, TWO_PI)


# -- sign conventions of other attitude sources (an INS, docs/conventions.md) --------------

__all__ += ["AttitudeConvention"]

_ROLL_WORDS = {"port-up": 1.0, "starboard-down": 1.0, "starboard-up": -1.0, "port-down": -1.0}
_PITCH_WORDS = {"bow-up": 1.0, "stern-down": 1.0, "bow-down": -1.0, "stern-up": -1.0}


class AttitudeConvention:
    """The signs of another source's heading, pitch and roll, mapped to shipstar's.

    Written ``"roll=port-up,pitch=bow-up,heading=true"`` (any order, any part left out
    takes shipstar's own: roll positive port up = starboard down, pitch positive bow up,
    heading true, from north through east).  ``roll`` is ``port-up`` (= ``starboard-down``)
    or ``starboard-up`` (= ``port-down``); ``pitch`` is ``bow-up`` (= ``stern-down``) or
    ``bow-down`` (= ``stern-up``); ``heading`` only ``true``.  Rates follow their angles.
    """

    __slots__ = ("roll_sign", "pitch_sign", "text")

    def __init__(self, text: str = ""):
        from shipstar.errors import ShipstarError

        roll, pitch = 1.0, 1.0
        given = set()
        for part in (p.strip() for p in str(text).split(",")):
            if not part:
                continue
            key, sep, value = (s.strip().lower() for s in part.partition("="))
            if not sep:
                raise ShipstarError(f"INS convention {part!r}: write key=value (roll=port-up|starboard-up, "
                                    f"pitch=bow-up|bow-down, heading=true)")
            if key in given:                        # the last one won: a sign chosen without a word
                raise ShipstarError(f"INS convention {text!r}: {key} given twice")
            given.add(key)
            if key == "roll" and value in _ROLL_WORDS:
                roll = _ROLL_WORDS[value]
            elif key == "pitch" and value in _PITCH_WORDS:
                pitch = _PITCH_WORDS[value]
            elif key == "heading" and value == "true":
                pass
            else:
                raise ShipstarError(f"INS convention {part!r}: roll must be port-up or starboard-up, pitch bow-up "
                                    f"or bow-down, heading true")
        self.roll_sign, self.pitch_sign = roll, pitch
        self.text = (f"roll={'port-up' if roll > 0 else 'starboard-up'},"
                     f"pitch={'bow-up' if pitch > 0 else 'bow-down'},heading=true")

    def __repr__(self) -> str:
        return f"AttitudeConvention({self.text!r})"

    def to_shipstar(self, heading, pitch, roll):
        """The source's (heading, pitch, roll) (or their rates) as shipstar's."""
        return heading, self.pitch_sign * np.asarray(pitch, float), self.roll_sign * np.asarray(roll, float)

    def from_shipstar(self, heading, pitch, roll):
        """shipstar's (heading, pitch, roll) (or rates) as the source writes them (the same signs:
        each mapping is its own inverse)."""
        return self.to_shipstar(heading, pitch, roll)
