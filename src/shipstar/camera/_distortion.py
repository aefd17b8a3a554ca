"""Weng lens distortion (seed 002 eq. 7): radial, decentring and thin-prism terms.

The model maps *ideal* (pinhole) image-plane offsets from the principal point to
*observed* ones, both in millimetres on the focal plane::

    u_obs = u + du(u, v),    v_obs = v + dv(u, v)

with ``u = (x - x0) * pixel_mm`` along a row (x right) and ``v = (y - y0) * pixel_mm``
down a column (y down), and, with ``r2 = u**2 + v**2``::

    du = k1 u r2 + k2 u r2**2 + k3 u r2**3 + p1 (3 u**2 + v**2) + 2 p2 u v + s1 r2
    dv = k1 v r2 + k2 v r2**2 + k3 v r2**3 + 2 p1 u v + p2 (u**2 + 3 v**2) + s2 r2

Seed 002 writes the same polynomial with ``g1 = s1 + p1, g2 = s2 + p2, g3 = 2 p1,
g4 = 2 p2`` (see :meth:`Distortion.from_seed002`).  The inverse (observed -> ideal) has
no closed form; :meth:`Distortion.undistort_mm` solves it by a vectorised Newton
iteration with the analytic 2 x 2 Jacobian.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, fields

import numpy as np

from shipstar.errors import ShipstarError

__all__ = ["Distortion"]

_MAX_ITER = 30
#: relative part of the residual tolerance (a few rounding units of the offset)
_TOL_REL = 1e-14


def _finite_float(owner: str, name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ShipstarError(f"{owner}: field {name!r} must be a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ShipstarError(f"{owner}: field {name!r} must be finite, got {value!r}")
    return value


@dataclass(frozen=True)
class Distortion:
    """Weng distortion coefficients; all zero (the default) means a pure pinhole.

    Attributes
    ----------
    k1_per_mm2, k2_per_mm4, k3_per_mm6 : float
        Radial terms (seed 002's kappa1..kappa3).
    p1_per_mm, p2_per_mm : float
        Decentring terms.
    s1_per_mm, s2_per_mm : float
        Thin-prism terms.

    Offsets are millimetres on the focal plane relative to the principal point, u along
    a row (x right), v down a column (y down); the model maps ideal -> observed.
    """

    k1_per_mm2: float = 0.0
    k2_per_mm4: float = 0.0
    k3_per_mm6: float = 0.0
    p1_per_mm: float = 0.0
    p2_per_mm: float = 0.0
    s1_per_mm: float = 0.0
    s2_per_mm: float = 0.0

    def __post_init__(self):
        values = []
        for f in fields(self):
            value = _finite_float("distortion", f.name, getattr(self, f.name))
            object.__setattr__(self, f.name, value)
            values.append(value)
        # made once: every project / unproject asks (not a field: eq, repr, replace ignore it)
        object.__setattr__(self, "_is_zero", all(v == 0.0 for v in values))

    # ------------------------------------------------------------------ seed 002 form
    @classmethod
    def from_seed002(cls, g1_per_mm, g2_per_mm, g3_per_mm, g4_per_mm,
                     kappa1_per_mm2, kappa2_per_mm4, kappa3_per_mm6) -> "Distortion":
        """Coefficients from seed 002 eq. 7's ``g1..g4, kappa1..kappa3``.

        ``p1 = g3 / 2, p2 = g4 / 2, s1 = g1 - g3 / 2, s2 = g2 - g4 / 2``; the kappas are
        the radial ``k1..k3``.  Seed 002's pixel axes are shipstar's (docs/conventions.md),
        so no sign changes.
        """
        g1, g2, g3, g4 = (float(g) for g in (g1_per_mm, g2_per_mm, g3_per_mm, g4_per_mm))
        return cls(k1_per_mm2=kappa1_per_mm2, k2_per_mm4=kappa2_per_mm4, k3_per_mm6=kappa3_per_mm6,
                   p1_per_mm=0.5 * g3, p2_per_mm=0.5 * g4,
                   s1_per_mm=g1 - 0.5 * g3, s2_per_mm=g2 - 0.5 * g4)

    @property
    def seed002_g_per_mm(self) -> tuple[float, float, float, float]:
        """Seed 002's ``(g1, g2, g3, g4)`` = ``(s1 + p1, s2 + p2, 2 p1, 2 p2)``."""
        return (self.s1_per_mm + self.p1_per_mm, self.s2_per_mm + self.p2_per_mm,
                2.0 * self.p1_per_mm, 2.0 * self.p2_per_mm)

    @property
    def is_zero(self) -> bool:
        """True when every coefficient is zero (pure pinhole)."""
        return self._is_zero

    def as_dict(self) -> dict[str, float]:
        """Plain ``{field: value}`` (the ``[distortion]`` table of a camera file)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    # ------------------------------------------------------------------ evaluation
    def _quadratic(self):
        """Seed 002's quadratic coefficients (a_uu, a_uv, a_vv) of du and (b_uu, b_uv, b_vv) of dv."""
        p1, p2, s1, s2 = self.p1_per_mm, self.p2_per_mm, self.s1_per_mm, self.s2_per_mm
        return (3.0 * p1 + s1, 2.0 * p2, p1 + s1), (p2 + s2, 2.0 * p1, 3.0 * p2 + s2)

    def offsets_mm(self, u_mm, v_mm):
        """Distortion ``(du, dv)`` (mm) at *ideal* offsets ``(u_mm, v_mm)`` (arrays, same shape)."""
        u = np.asarray(u_mm, float)
        v = np.asarray(v_mm, float)
        (a_uu, a_uv, a_vv), (b_uu, b_uv, b_vv) = self._quadratic()
        with np.errstate(over="ignore", invalid="ignore"):    # absurd offsets give inf, not a warning
            uu, uv, vv = u * u, u * v, v * v
            r2 = uu + vv
            radial = r2 * (self.k1_per_mm2 + r2 * (self.k2_per_mm4 + r2 * self.k3_per_mm6))
            du = a_uu * uu + a_uv * uv + a_vv * vv + u * radial
            dv = b_uu * uu + b_uv * uv + b_vv * vv + v * radial
        return du, dv

    def distort_mm(self, uv_mm) -> np.ndarray:
        """Ideal -> observed offsets: ``(..., 2)`` mm -> ``(..., 2)`` mm."""
        uv = np.asarray(uv_mm, float)
        du, dv = self.offsets_mm(uv[..., 0], uv[..., 1])
        return np.stack([uv[..., 0] + du, uv[..., 1] + dv], axis=-1)

    def undistort_mm(self, uv_obs_mm, tol_mm: float = 1e-11) -> np.ndarray:
        """Observed -> ideal offsets ``(..., 2)`` mm by Newton iteration.

        Iterates until the residual ``|distort(ideal) - observed|`` is below ``tol_mm``
        (quadratic convergence: one or two steps for the seeds' coefficients).  Rows that
        are not finite, or where the iteration does not converge to the physical inverse
        (far outside the region where the polynomial is invertible), are NaN.
        """
        uv = np.asarray(uv_obs_mm, float)
        u, v = self._solve(uv[..., 0].ravel(), uv[..., 1].ravel(), tol_mm)
        return np.stack([u, v], axis=-1).reshape(uv.shape)

    def _solve(self, u_obs, v_obs, tol_mm):
        """Newton solve of ``(u, v) + d(u, v) = (u_obs, v_obs)`` on 1-D arrays."""
        zo = u_obs + 1j * v_obs
        ok = np.isfinite(zo)
        all_ok = bool(ok.all())
        if not all_ok:
            zo = np.where(ok, zo, 0.0)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            z, converged = self._newton(zo, tol_mm + _TOL_REL * np.abs(zo))
        if not all_ok:
            converged &= ok
        z = np.where(converged, z, complex(np.nan, np.nan))
        return z.real, z.imag

    def _complex_coefficients(self):
        """``(c1, c2)`` of the quadratic part written in ``z = u + i v``:
        ``du + i dv = c1 z**2 + c2 |z|**2 + z * radial(|z|**2)``."""
        p1, p2, s1, s2 = self.p1_per_mm, self.p2_per_mm, self.s1_per_mm, self.s2_per_mm
        return complex(p1, -p2), complex(2.0 * p1 + s1, 2.0 * p2 + s2)

    def _newton(self, zo, tol_mm):
        """Newton in complex form.  With ``F(z) = z + d(z) - zo``, ``A = dF/dz`` and
        ``B = dF/dconj(z)`` (Wirtinger derivatives), the step solving
        ``F + A dz + B conj(dz) = 0`` is ``dz = (B conj(F) - conj(A) F) / (|A|^2 - |B|^2)``;
        the denominator is the determinant of the real 2 x 2 Jacobian."""
        c1, c2 = self._complex_coefficients()
        k1, k2, k3 = self.k1_per_mm2, self.k2_per_mm4, self.k3_per_mm6
        k2x2, k3x3 = 2.0 * k2, 3.0 * k3
        t = zo.real * zo.real + zo.imag * zo.imag
        z = zo - (zo * (c1 * zo + t * (k1 + t * (k2 + t * k3))) + c2 * t)   # first-order inverse
        det = None
        for it in range(_MAX_ITER + 1):
            zc = z.conj()
            t = (z * zc).real
            radial = t * (k1 + t * (k2 + t * k3))
            F = z * (1.0 + c1 * z + radial) + c2 * t - zo
            res = np.abs(F)
            # at least one step, so that the determinant at the solution is known
            if det is not None and (not np.any(res > tol_mm) or it == _MAX_ITER):
                break
            dradial = k1 + t * (k2x2 + k3x3 * t)           # d(radial)/dt
            A = 1.0 + 2.0 * c1 * z + c2 * zc + radial + t * dradial
            B = z * (c2 + z * dradial)
            Ac = A.conj()
            det = (A * Ac).real - (B * B.conj()).real
            z = z + (B * F.conj() - Ac * F) / det
        # a root beyond a fold of the polynomial (det <= 0) is not the physical inverse
        converged = (res <= tol_mm) & (det > 0.0)
        return z, converged

    def jacobian(self, u_mm, v_mm) -> np.ndarray:
        """d(observed)/d(ideal) at ideal offsets, shape ``S + (2, 2)``."""
        u = np.asarray(u_mm, float)
        v = np.asarray(v_mm, float)
        (a_uu, a_uv, a_vv), (b_uu, b_uv, b_vv) = self._quadratic()
        r2 = u * u + v * v
        k1, k2, k3 = self.k1_per_mm2, self.k2_per_mm4, self.k3_per_mm6
        radial = r2 * (k1 + r2 * (k2 + r2 * k3))
        dradial = 2.0 * (k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2))
        out = np.empty(u.shape + (2, 2))
        out[..., 0, 0] = 1.0 + 2.0 * a_uu * u + a_uv * v + radial + dradial * u * u
        out[..., 0, 1] = a_uv * u + 2.0 * a_vv * v + dradial * u * v
        out[..., 1, 0] = 2.0 * b_uu * u + b_uv * v + dradial * u * v
        out[..., 1, 1] = 1.0 + b_uv * u + 2.0 * b_vv * v + radial + dradial * v * v
        return out
