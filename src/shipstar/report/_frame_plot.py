"""A raw frame with its detected and identified stars marked."""

from __future__ import annotations

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.report._figure import new_figure, png_bytes

__all__ = ["plot_frame_stars"]

#: HIP labels are written next to this many of the brightest identified stars.
MAX_LABELS = 25


def _stretch(image: np.ndarray) -> np.ndarray:
    """Display stretch in [0, 1]: background (up to 1.5 sigma above the median) at 0, asinh
    above it, the brightest 0.02 % of pixels saturated (faint stars stay visible)."""
    img = np.asarray(image, float)
    bg = float(np.median(img))
    noise = float(np.median(np.abs(img - bg))) * 1.4826 or 1.0
    x = np.arcsinh(np.maximum(img - bg - 1.5 * noise, 0.0) / noise)
    top = float(np.percentile(x, 99.98)) or 1.0
    return np.clip(x / top, 0.0, 1.0)


def plot_frame_stars(image, *, detected_xy_px, identified_xy_px, identified_hip, title: str = "") -> bytes:
    """PNG of a frame with stars marked.

    Parameters
    ----------
    image : (H, W) array
        Raw frame (ADU).
    detected_xy_px : (N, 2)
        Every extracted star (small squares).
    identified_xy_px : (M, 2)
        Identified stars (circles), brightest first.
    identified_hip : (M,) int
        Their Hipparcos numbers (labels on the brightest ``MAX_LABELS``).
    title : str

    Returns
    -------
    bytes
    """
    img = np.asarray(image)
    if img.ndim != 2:
        raise ShipstarError(f"image must be 2-D, got shape {img.shape}")
    det = np.asarray(detected_xy_px, float).reshape(-1, 2)
    ide = np.asarray(identified_xy_px, float).reshape(-1, 2)
    hip = np.asarray(identified_hip).reshape(-1)
    if len(hip) != len(ide):
        raise ShipstarError("identified_hip must have one entry per identified star")
    fig, axes = new_figure(7.2, 7.6)
    ax = axes[0, 0]
    h, w = img.shape
    ax.imshow(_stretch(img), cmap="gray", origin="upper", extent=(-0.5, w - 0.5, h - 0.5, -0.5),
              interpolation="nearest")
    ax.plot(det[:, 0], det[:, 1], "s", ms=9, mfc="none", mec="#ffb000", mew=0.8,
            label=f"detected ({len(det)})")
    ax.plot(ide[:, 0], ide[:, 1], "o", ms=15, mfc="none", mec="#3ddc84", mew=1.2,
            label=f"identified ({len(ide)})")
    for (x, y), n in zip(ide[:MAX_LABELS], hip[:MAX_LABELS]):
        ax.annotate(f"HIP {int(n)}", (x, y), xytext=(8, -8), textcoords="offset points", color="#3ddc84",
                    fontsize=6.5)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_xlabel("x (px, right)")
    ax.set_ylabel("y (px, down)")
    ax.set_title(title, fontsize=9, wrap=True)
    ax.legend(loc="upper right", fontsize=8, framealpha=0.8)
    return png_bytes(fig, dpi=100)
