"""Benchmark: the closed-form Jacobian of the error model against its anchor, central finite
differences of the full nonlinear chain (what a sweep would cost without the closed form),
and the Monte Carlo check.  Prints times and ratios; run: python benchmarks/bench_errormodel.py
"""

from __future__ import annotations

import time

import numpy as np

import shipstar.errormodel as em
from shipstar import frames as F


def fd_jacobian(x, h=1e-5):
    """Central differences through frames' chain, vectorised over points (the anchor)."""
    J = np.empty(x.shape[:-1] + (3, 6))
    for j in range(6):
        xp, xm = x.copy(), x.copy()
        xp[..., j] += h
        xm[..., j] -= h
        J[..., j] = F.wrap_pi(em.ship_angles_rad(xp[..., :3], xp[..., 3:])
                              - em.ship_angles_rad(xm[..., :3], xm[..., 3:])) / (2 * h)
    return J


def best_time(fn, repeat=5):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    rng = np.random.default_rng(0)
    n = 20000
    x = rng.uniform(-np.pi, np.pi, (n, 6))
    x[:, 1] *= 0.45
    x[:, 4] *= 0.45
    t_an = best_time(lambda: em.ship_jacobian(x[:, :3], x[:, 3:]))
    t_fd = best_time(lambda: fd_jacobian(x))
    J, Jf = em.ship_jacobian(x[:, :3], x[:, 3:]), fd_jacobian(x)
    C_hd, _, _ = em.ship_matrix(x[:, :3], x[:, 3:])
    ok = np.hypot(C_hd[:, 0, 0], C_hd[:, 2, 0]) > 0.05           # more than 3 deg from gimbal lock
    rel = np.max(np.abs(J - Jf), axis=(1, 2)) / np.max(np.abs(Jf), axis=(1, 2))
    print(f"Jacobian of {n} attitudes: closed form {t_an * 1e3:.1f} ms, finite differences {t_fd * 1e3:.1f} ms, "
          f"ratio {t_fd / t_an:.1f}x; worst relative difference {np.max(rel[ok]):.1e} ({ok.sum()} points)")
    base = np.array([235.0, 45.0, 90.0, 0.0, 35.0, 0.0]) * np.pi / 180
    t_mc = best_time(lambda: em.monte_carlo_check(base[:3], base[3:], (200,) * 6, n_samples=20000, rng=1), 3)
    t_lin = best_time(lambda: em.error_budget(base[:3], base[3:], (200,) * 6))
    print(f"one error budget: linear {t_lin * 1e6:.0f} us, Monte Carlo (20000 draws) {t_mc * 1e3:.1f} ms, "
          f"ratio {t_mc / t_lin:.0f}x")


if __name__ == "__main__":
    main()
