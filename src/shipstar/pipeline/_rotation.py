"""Small-rotation helpers: rotation vector <-> matrix (body-axes increments)."""

from __future__ import annotations

import math

import numpy as np

from shipstar.frames import rotation_angle_rad

__all__ = ["rotvec", "expm_rotvec"]


def rotvec(C) -> np.ndarray:
    """Rotation vector ``phi`` (3,) with ``C = exp([phi x])``, for rotation angles below pi."""
    C = np.asarray(C, float)
    s = np.array([C[2, 1] - C[1, 2], C[0, 2] - C[2, 0], C[1, 0] - C[0, 1]])
    n = float(np.linalg.norm(s))
    if n == 0.0:
        return np.zeros(3)
    return s / n * float(rotation_angle_rad(C))


def expm_rotvec(phi) -> np.ndarray:
    """Rotation matrix ``exp([phi x])`` of a rotation vector ``phi`` (3,) (Rodrigues)."""
    phi = np.asarray(phi, float)
    a = float(np.linalg.norm(phi))
    if a == 0.0:
        return np.eye(3)
    k = phi / a
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(a) * K + (1.0 - math.cos(a)) * (K @ K)
