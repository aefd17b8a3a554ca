"""Refraction formulas (private): the seeds' almanac/Pulkovo model and ERFA's refco model.

Each function takes OBSERVED elevations in radians (any shape) and returns the refraction
rho in radians (same shape), without any range checks: :mod:`shipstar.sky.refraction`
validates its inputs and calls these.  See ``docs/refraction.md`` for the derivations,
the typos fixed in the seeds and the accuracy against ray tracing.
"""

from __future__ import annotations

import functools

import numpy as np

from shipstar.units import ASEC2RAD, DEG2RAD

__all__ = [
    "CAA_RHO0_ARCSEC", "CAA_ALPHA_T", "PULKOVO_RHO0_ARCSEC",
    "CAA_PRESSURE_REF_HPA", "PULKOVO_PRESSURE_REF_HPA",
    "BLEND_PULKOVO_CAA_DEG", "BLEND_ALPHA_T_DEG",
    "rho_caa_rad", "rho_pulkovo_rad", "rho_almanac_rad", "rho_erfa_rad", "erfa_coefficients_rad",
]

#: Seed 000 eq. 10: mean refraction of the Chinese Astronomical Almanac, coefficients of
#: tan Z ... tan^5 Z in arcsec (Z: observed zenith distance).
CAA_RHO0_ARCSEC = (60.0972468, 0.0109332, -0.0729002, 0.0018327, -0.0000107)

#: Seed 000 eq. 11: temperature-factor multiplier alpha_t, coefficients of tan^0 ... tan^5 Z.
#: The printed last term "- -0.0001700" is read as "- 0.0001700" (alternating series; the
#: other sign makes alpha_t = 1.37 at 14 deg, against 1.02 from ray tracing; see the docs).
CAA_ALPHA_T = (1.0, -0.0072027, 0.0133651, -0.0073417, 0.0018700, -0.0001700)

#: Seed 000 eq. 14: Pulkovo mean refraction, {power of tan Z: coefficient in arcsec}.  The
#: printed "-2.87'' tan^7 Z" is -2.87e-7'' tan^7 Z (ray tracing; see the docs).
PULKOVO_RHO0_ARCSEC = {1: 60.2293, 3: -0.06560, 5: 0.00016113, 7: -2.87e-7}

#: Seed 000 eq. 12 and 13 reference pressures (760 mmHg, printed two ways).
CAA_PRESSURE_REF_HPA = 1013.2472
PULKOVO_PRESSURE_REF_HPA = 1013.25

#: Observed-elevation band (deg) over which the Pulkovo branch hands over to the almanac
#: branch (the seed switches at 14 deg, where the two disagree by ~1'').
BLEND_PULKOVO_CAA_DEG = (13.0, 15.0)

#: Band (deg) over which alpha_t goes from its polynomial (seed: E <= 45 deg) to 1 (E > 45).
BLEND_ALPHA_T_DEG = (45.0, 46.0)


def _smoothstep(el_rad, band_deg):
    """0 below the band, 1 above, ``3x^2 - 2x^3`` inside: C1-continuous weights."""
    lo, hi = band_deg[0] * DEG2RAD, band_deg[1] * DEG2RAD
    x = np.clip((el_rad - lo) / (hi - lo), 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _tan_z(el_rad):
    return np.cos(el_rad) / np.sin(el_rad)


def _horner(coeffs_low_to_high, t):
    acc = np.full_like(t, coeffs_low_to_high[-1])
    for c in coeffs_low_to_high[-2::-1]:
        acc = acc * t + c
    return acc


def rho_caa_rad(el_rad, pressure_hpa, temperature_c, *, alpha_blend=True):
    """Seed 000 eq. 9-12: ``rho = (1 + alpha_t A_t + B) rho0`` (Chinese Astronomical Almanac).

    ``alpha_t`` is the eq. 11 polynomial up to 45 deg and 1 above; with ``alpha_blend`` the
    change happens smoothly over :data:`BLEND_ALPHA_T_DEG` (the polynomial is 1.00052,
    not 1, at 45 deg), otherwise it is the seed's step at exactly 45 deg.
    """
    el = np.asarray(el_rad, dtype=float)
    t = _tan_z(el)
    rho0 = t * _horner(CAA_RHO0_ARCSEC, t)
    alpha_poly = _horner(CAA_ALPHA_T, t)
    if alpha_blend:
        w = _smoothstep(el, BLEND_ALPHA_T_DEG)
    else:
        w = (el > 45.0 * DEG2RAD).astype(float)
    alpha_t = alpha_poly + w * (1.0 - alpha_poly)
    a_t = -0.00383 * temperature_c / (1.0 + 0.00367 * temperature_c)
    b = pressure_hpa / CAA_PRESSURE_REF_HPA - 1.0
    return (1.0 + alpha_t * a_t + b) * rho0 * ASEC2RAD


def rho_pulkovo_rad(el_rad, pressure_hpa, temperature_c):
    """Seed 000 eq. 13-14: ``rho = P/1013.25 * 273.15/(273.15 + t) * rho0`` (Pulkovo)."""
    t = _tan_z(np.asarray(el_rad, dtype=float))
    t2 = t * t
    c = PULKOVO_RHO0_ARCSEC
    rho0 = t * (c[1] + t2 * (c[3] + t2 * (c[5] + t2 * c[7])))
    factor = pressure_hpa / PULKOVO_PRESSURE_REF_HPA * 273.15 / (273.15 + temperature_c)
    return factor * rho0 * ASEC2RAD


def rho_almanac_rad(el_rad, pressure_hpa, temperature_c):
    """The seeds' model: Pulkovo below 13 deg, almanac above 15 deg, C1 blend in between."""
    el = np.asarray(el_rad, dtype=float)
    w = _smoothstep(el, BLEND_PULKOVO_CAA_DEG)
    caa = rho_caa_rad(el, pressure_hpa, temperature_c)
    pulkovo = rho_pulkovo_rad(el, pressure_hpa, temperature_c)
    return pulkovo + w * (caa - pulkovo)


@functools.lru_cache(maxsize=64)
def erfa_coefficients_rad(pressure_hpa, temperature_c, relative_humidity, wavelength_um):
    """``(A, B)`` of ERFA's ``refco``: ``rho = A tan Z + B tan^3 Z`` (radians)."""
    import erfa

    a, b = erfa.refco(pressure_hpa, temperature_c, relative_humidity, wavelength_um)
    return float(a), float(b)


def rho_erfa_rad(el_rad, pressure_hpa, temperature_c, relative_humidity, wavelength_um):
    """ERFA/SOFA two-term model ``A tan Z + B tan^3 Z`` with A, B from ``erfa.refco``."""
    a, b = erfa_coefficients_rad(pressure_hpa, temperature_c, relative_humidity, wavelength_um)
    t = _tan_z(np.asarray(el_rad, dtype=float))
    return (a + b * t * t) * t
