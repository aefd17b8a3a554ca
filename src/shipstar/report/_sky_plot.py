"""Sky chart: where each sensor looks, over the horizon, with the bright stars."""

from __future__ import annotations

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.report._figure import color_for, new_figure, png_bytes

__all__ = ["plot_sky_chart"]


def _r(el_deg):
    return 90.0 - np.asarray(el_deg, float)


def _theta(az_deg):
    return np.unwrap(np.radians(np.asarray(az_deg, float)))


def plot_sky_chart(*, tracks_deg: dict, footprints_deg: dict, stars_az_el_deg, stars_mag,
                   heading_deg: float | None = None, title: str = "") -> bytes:
    """PNG of a plan-view sky chart (zenith at the centre, north up, east right).

    Parameters
    ----------
    tracks_deg : dict of name -> (M, 2)
        Each sensor's boresight (azimuth, elevation) over a session, deg.
    footprints_deg : dict of name -> (K, 2)
        Each sensor's field outline (azimuth, elevation) at one instant, deg.
    stars_az_el_deg : (N, 2)
        Bright stars above the horizon.
    stars_mag : (N,)
    heading_deg : float, optional
        The ship's heading (an arrow toward the bow).
    title : str
    """
    stars = np.asarray(stars_az_el_deg, float).reshape(-1, 2)
    mag = np.asarray(stars_mag, float).reshape(-1)
    if len(mag) != len(stars):
        raise ShipstarError("stars_mag must have one entry per star")
    fig, axes = new_figure(7.0, 7.0, projection="polar")
    ax = axes[0, 0]
    ax.set_theta_zero_location("N")
    ax.set_theta_direction(-1)
    up = stars[:, 1] > 0
    size = np.clip(14.0 * 10 ** (-0.25 * (mag[up] - 1.0)), 0.6, 40.0)
    ax.scatter(np.radians(stars[up, 0]), _r(stars[up, 1]), s=size, c="#4a5563", lw=0, zorder=1)
    for k, (name, tr) in enumerate(tracks_deg.items()):
        tr = np.asarray(tr, float).reshape(-1, 2)
        col = color_for(name, k)
        ax.plot(_theta(tr[:, 0]), _r(tr[:, 1]), "-", color=col, lw=2.2, zorder=3, label=f"{name} boresight")
        fp = np.asarray(footprints_deg.get(name, np.zeros((0, 2))), float).reshape(-1, 2)
        if len(fp):
            closed = np.vstack([fp, fp[:1]])
            ax.fill(_theta(closed[:, 0]), _r(closed[:, 1]), color=col, alpha=0.25, zorder=2)
            ax.plot(_theta(closed[:, 0]), _r(closed[:, 1]), color=col, lw=1.0, zorder=2)
    if heading_deg is not None:
        ax.annotate("", xy=(np.radians(heading_deg), 80.0), xytext=(0.0, 0.0),
                    arrowprops=dict(arrowstyle="-|>", color="#222", lw=1.6))
        ax.text(np.radians(heading_deg), 84.0, "bow", ha="center", va="center", fontsize=9)
    ax.set_rlim(0.0, 90.0)
    ax.set_rticks([30.0, 60.0, 90.0])
    ax.set_yticklabels(["60\u00b0", "30\u00b0", "0\u00b0"], fontsize=7)
    ax.set_xticks(np.radians([0, 45, 90, 135, 180, 225, 270, 315]))
    ax.set_xticklabels(["N", "NE", "E", "SE", "S", "SW", "W", "NW"])
    ax.set_title(title, fontsize=10)
    ax.legend(loc="lower left", bbox_to_anchor=(-0.08, -0.08), fontsize=8)
    return png_bytes(fig, dpi=100)
