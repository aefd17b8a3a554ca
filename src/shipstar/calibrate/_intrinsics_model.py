"""Intrinsic parameter vector and the star vectors it gives, with analytic derivatives.

The parameters are those of :class:`shipstar.camera.Camera` that shape the geometry:
``f_mm``, ``x0_px``, ``y0_px`` and the seven Weng coefficients (docs/camera.md).  The
pixel pitch is a known detector property and stays fixed: star frames only measure
``f_mm / pixel_mm``.

A measured centroid ``xy_px`` gives the observed focal-plane offset
``z_obs = (xy - (x0, y0)) * pixel_mm`` (mm); the ideal (pinhole) offset ``z`` solves
``z + d(z; c) = z_obs`` (the camera's exact inverse of the Weng model), and the sensor
vector is ``w = [f, -v, u] / |[f, -v, u]|`` with ``z = (u, v)``.  The derivatives follow
from the implicit function theorem: ``J_d dz = dz_obs - B dc`` with ``J_d`` the 2 x 2
Jacobian of ``z -> z + d(z)`` and ``B`` the 2 x 7 derivative of ``d`` by the coefficients.

Internally the solver works on *scaled* parameters ``phi = theta / scale``; a unit step of
any ``phi`` moves a star at the edge of the field by about one pixel, which keeps the
normal equations well conditioned.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shipstar.camera import Camera, Distortion

__all__ = ["TERMS", "TERM_FIELDS", "PARAM_NAMES", "ParamSpace", "sensor_vectors"]

#: Weng distortion terms, short names (docs/camera.md)
TERMS = ("k1", "k2", "k3", "p1", "p2", "s1", "s2")
#: the Distortion field of each term
TERM_FIELDS = {"k1": "k1_per_mm2", "k2": "k2_per_mm4", "k3": "k3_per_mm6",
               "p1": "p1_per_mm", "p2": "p2_per_mm", "s1": "s1_per_mm", "s2": "s2_per_mm"}
#: every geometric parameter, in the order of the full vector
PARAM_NAMES = ("f_mm", "x0_px", "y0_px") + tuple(TERM_FIELDS[t] for t in TERMS)
#: power of the field radius by which each distortion term's effect grows
_RADIUS_POWER = {"k1": 3, "k2": 5, "k3": 7, "p1": 2, "p2": 2, "s1": 2, "s2": 2}


def _term_basis(u, v):
    """``d(du, dv) / d(coefficient)`` at ideal offsets: shape ``(N, 2, 7)`` in TERMS order."""
    uu, uv, vv = u * u, u * v, v * v
    r2 = uu + vv
    r4 = r2 * r2
    r6 = r4 * r2
    out = np.empty(u.shape + (2, 7))
    out[..., 0, 0], out[..., 1, 0] = u * r2, v * r2
    out[..., 0, 1], out[..., 1, 1] = u * r4, v * r4
    out[..., 0, 2], out[..., 1, 2] = u * r6, v * r6
    out[..., 0, 3], out[..., 1, 3] = 3.0 * uu + vv, 2.0 * uv
    out[..., 0, 4], out[..., 1, 4] = 2.0 * uv, uu + 3.0 * vv
    out[..., 0, 5], out[..., 1, 5] = r2, 0.0
    out[..., 0, 6], out[..., 1, 6] = 0.0, r2
    return out


@dataclass(frozen=True)
class ParamSpace:
    """Which parameters are free, their scales, and the camera they start from.

    Attributes
    ----------
    base : Camera
        Supplies the pixel pitch, the image size and the values of fixed parameters.
    free : tuple of str
        Names (from :data:`PARAM_NAMES`) being estimated, in vector order.
    r_max_mm : float
        Largest distance of the image corners from the principal point (sets the scales).
    """

    base: Camera
    free: tuple
    r_max_mm: float

    @classmethod
    def for_camera(cls, camera: Camera, free) -> "ParamSpace":
        w, h = camera.width_px, camera.height_px
        corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]])
        d = (corners - [camera.x0_px, camera.y0_px]) * camera.pixel_mm
        return cls(camera, tuple(free), float(np.hypot(d[:, 0], d[:, 1]).max()))

    @property
    def scales(self) -> np.ndarray:
        """Parameter change that moves an edge star by about 1 px, per free parameter."""
        pix, r = self.base.pixel_mm, self.r_max_mm
        out = []
        for name in self.free:
            if name == "f_mm":
                out.append(self.base.f_mm * pix / r)
            elif name in ("x0_px", "y0_px"):
                out.append(1.0)
            else:
                term = next(t for t, f in TERM_FIELDS.items() if f == name)
                out.append(pix / r ** _RADIUS_POWER[term])
        return np.array(out)

    def values(self, camera: Camera) -> np.ndarray:
        """Free parameter values of ``camera`` (natural units)."""
        full = full_vector(camera)
        return np.array([full[PARAM_NAMES.index(n)] for n in self.free])

    def full(self, theta) -> np.ndarray:
        """The 10-vector of all parameters with ``theta`` in the free slots."""
        out = full_vector(self.base)
        for name, value in zip(self.free, np.asarray(theta, float)):
            out[PARAM_NAMES.index(name)] = value
        return out

    def camera(self, theta) -> Camera:
        """The base camera with the free parameters set to ``theta`` (validated)."""
        return camera_from_full(self.base, self.full(theta))

    def with_free(self, free) -> "ParamSpace":
        return ParamSpace(self.base, tuple(free), self.r_max_mm)

    def with_base(self, camera: Camera) -> "ParamSpace":
        return ParamSpace(camera, self.free, self.r_max_mm)


def full_vector(camera: Camera) -> np.ndarray:
    """All geometric parameters of a camera as a 10-vector (PARAM_NAMES order)."""
    d = camera.distortion
    return np.array([camera.f_mm, camera.x0_px, camera.y0_px]
                    + [getattr(d, TERM_FIELDS[t]) for t in TERMS], dtype=float)


def camera_from_full(base: Camera, full) -> Camera:
    """``base`` with the geometric parameters replaced by the 10-vector ``full``."""
    full = [float(x) for x in full]
    dist = Distortion(**{TERM_FIELDS[t]: full[3 + i] for i, t in enumerate(TERMS)})
    return base.replace(f_mm=full[0], x0_px=full[1], y0_px=full[2], distortion=dist)


def sensor_vectors(xy_px, full, pixel_mm: float, free, *, want_xy: bool = False):
    """Sensor unit vectors of centroids and their derivatives.

    Parameters
    ----------
    xy_px : ndarray (N, 2)
        Measured (distorted) centroids.
    full : ndarray (10,)
        All geometric parameters (PARAM_NAMES order).
    pixel_mm : float
    free : sequence of str
        Parameters to differentiate by (natural units).
    want_xy : bool
        Also return ``dw / dxy``.

    Returns
    -------
    w : ndarray (N, 3)
        Unit vectors (X boresight, Y image up, Z image right); NaN rows where the
        distortion has no inverse.
    dw_dtheta : ndarray (N, 3, P)
    dw_dxy : ndarray (N, 3, 2), only with ``want_xy``
    """
    xy = np.asarray(xy_px, float)
    f, x0, y0 = full[0], full[1], full[2]
    coeffs = full[3:]
    dist = Distortion(**{TERM_FIELDS[t]: float(c) for t, c in zip(TERMS, coeffs)})
    z_obs = np.stack([(xy[:, 0] - x0) * pixel_mm, (xy[:, 1] - y0) * pixel_mm], axis=-1)
    if dist.is_zero:
        z = z_obs
        jac_inv = np.broadcast_to(np.eye(2), (len(xy), 2, 2))
    else:
        z = dist.undistort_mm(z_obs)
        jac_inv = np.linalg.inv(dist.jacobian(z[:, 0], z[:, 1]))
    u, v = z[:, 0], z[:, 1]
    q = np.stack([np.full_like(u, f), -v, u], axis=-1)
    norm = np.sqrt(np.einsum("ni,ni->n", q, q))
    w = q / norm[:, None]
    proj = (np.eye(3)[None] - w[:, :, None] * w[:, None, :]) / norm[:, None, None]   # dw/dq
    dq_dz = np.array([[0.0, 0.0], [0.0, -1.0], [1.0, 0.0]])                        # q = [f, -v, u]
    dw_dz = proj @ dq_dz                                                            # (N, 3, 2)
    basis = _term_basis(u, v)
    cols = []
    for name in free:
        if name == "f_mm":
            cols.append(proj[:, :, 0])
        elif name == "x0_px":
            cols.append(np.einsum("nij,nj->ni", dw_dz, jac_inv[:, :, 0] * -pixel_mm))
        elif name == "y0_px":
            cols.append(np.einsum("nij,nj->ni", dw_dz, jac_inv[:, :, 1] * -pixel_mm))
        else:
            term = next(t for t, fld in TERM_FIELDS.items() if fld == name)
            dz = -np.einsum("nij,nj->ni", jac_inv, basis[:, :, TERMS.index(term)])
            cols.append(np.einsum("nij,nj->ni", dw_dz, dz))
    dw_dtheta = np.stack(cols, axis=-1) if cols else np.zeros((len(xy), 3, 0))
    if want_xy:
        return w, dw_dtheta, dw_dz @ (jac_inv * pixel_mm)
    return w, dw_dtheta
