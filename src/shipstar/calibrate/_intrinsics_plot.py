"""Residual vectors over the sensor, before and after an intrinsic calibration."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from shipstar.errors import ShipstarError

__all__ = ["plot_residuals"]


def _panel(ax, cal, cam, residual, title, scale_px_per_px):
    w, h = cam.width_px, cam.height_px
    ax.add_patch(_rect(w, h))
    xy = cal.xy_px
    ax.quiver(xy[:, 0], xy[:, 1], residual[:, 0], residual[:, 1], angles="xy", scale_units="xy",
              scale=1.0 / scale_px_per_px, width=0.002, color="tab:blue")
    ax.plot([cam.x0_px], [cam.y0_px], "+", color="tab:red", ms=10, label="principal point")
    rms = float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1))))
    ax.set_title(f"{title}: rms {rms:.3f} px")
    ax.set_xlim(-0.05 * w, 1.05 * w)
    ax.set_ylim(1.05 * h, -0.05 * h)          # y down, as in the image
    ax.set_aspect("equal")
    ax.set_xlabel("x (px)")
    ax.set_ylabel("y (px)")


def _rect(w, h):
    from matplotlib.patches import Rectangle

    return Rectangle((-0.5, -0.5), w, h, fill=False, color="0.5", lw=1.0)


def plot_residuals(cal, path) -> Path:
    """Write a PNG with each star's residual vector (measured minus predicted centroid,
    the frame's attitude fitted) over the sensor: input camera left, calibrated right.

    The arrows are magnified so that the largest "after" residual spans ~5 % of the image
    width (the factor is in the title); the "before" panel uses its own factor.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if cal.xy_px is None or len(cal.xy_px) == 0:
        raise ShipstarError("no residuals to plot")
    path = Path(path)
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.2), constrained_layout=True)
    width = cal.camera.width_px
    before = cal.input_camera if cal.input_camera is not None else cal.camera
    for ax, cam, res, name in ((axes[0], before, cal.residual_before_px, "input camera"),
                               (axes[1], cal.camera, cal.residual_after_px, f"calibrated ({cal.method})")):
        big = float(np.percentile(np.hypot(res[:, 0], res[:, 1]), 99)) or 1.0
        factor = 0.05 * width / big
        _panel(ax, cal, cam, res, f"{name}, arrows x{factor:.0f}", factor)
    axes[1].legend(loc="lower right", fontsize=8)
    fig.suptitle(f"{cal.camera.name}: residual vectors of {cal.n_stars} stars in {cal.n_frames} frames; "
                 f"interstar rms {cal.rms_before_arcsec:.2f}\" -> {cal.rms_after_arcsec:.3f}\"")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=110)
    except OSError as exc:
        raise ShipstarError(f"cannot write plot {str(path)!r}: {exc.strerror or exc}") from None
    finally:
        plt.close(fig)
    return path
