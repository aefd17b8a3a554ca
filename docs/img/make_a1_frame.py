"""Make docs/img/a1_frame.png: a simulated A1 frame at the seed-000 dock, stars extracted and circled.

Run from anywhere: ``python docs/img/make_a1_frame.py [--out PATH]``.  The scene is seed
000's dock calibration: 2013-03-15 20:16 local (12:16 UTC) at Jiangyin, ship heading
46 deg 28' 28.51'', level, 11.10 C, 1021.70 hPa, sensor A1 at its calibrated
installation angles (Tab. 2).  One satellite trail and a few cosmic-ray hits are added
so that the figure also shows objects that are not catalog stars.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from shipstar.camera import camera_preset
from shipstar.extract import extract_stars
from shipstar.simulate import ShipPose, random_false_objects, simulate_frame
from shipstar.sky.apparent import Site
from shipstar.sky.refraction import Weather

SEED = 20130315
HEADING_DEG = 46.0 + 28.0 / 60.0 + 28.51 / 3600.0
MATCH_RADIUS_PX = 1.5


def simulate():
    camera = camera_preset("A1")
    ship = ShipPose.from_deg(HEADING_DEG, 0.0, 0.0, 185.1093, 39.3734, -0.2262)
    objects = random_false_objects(camera, np.random.default_rng([SEED, 1]), trails=1, cosmic_rays=6)
    return simulate_frame(camera, ship=ship, utc_iso="2013-03-15T12:16:00", site=Site.from_deg(31.9, 120.3, 5.0),
                          weather=Weather(pressure_hpa=1021.7, temperature_c=11.1), seed=SEED,
                          false_objects=objects)


def match(truth_xy, found_xy):
    """For each extracted star, the index of the nearest true star within the radius (-1: none)."""
    from scipy.spatial import cKDTree

    dist, idx = cKDTree(truth_xy).query(found_xy, distance_upper_bound=MATCH_RADIUS_PX)
    return np.where(np.isfinite(dist), idx, -1), dist


def draw(frame, ext, out: Path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    stars = frame.stars
    which, dist = match(stars.xy_px, ext.xy_px)
    ok = which >= 0
    img = frame.image.astype(float) - np.median(frame.image)
    shown = np.arcsinh(np.clip(img, 0, None) / (3.0 * ext.noise_adu))
    width_in, height_in = 16.0, 10.9                      # image shown at 1 screen pixel per pixel
    fig = plt.figure(figsize=(width_in, height_in), dpi=100)
    ax = fig.add_axes([0.005, 0.01, 1024 / (100 * width_in), 1024 / (100 * height_in)])
    ax.imshow(shown, cmap="gray", origin="upper", vmin=0, vmax=np.percentile(shown, 99.95),
              interpolation="nearest")
    ax.scatter(*ext.xy_px[ok].T, s=140, facecolors="none", edgecolors="#3ddc84", linewidths=1.0,
               label=f"extracted, matched to a catalog star ({ok.sum()})")
    ax.scatter(*ext.xy_px[~ok].T, s=180, facecolors="none", edgecolors="#ff5050", linewidths=1.2,
               label=f"extracted, not a catalog star ({(~ok).sum()})")
    missed = np.setdiff1d(np.arange(len(stars)), which[ok])
    ax.scatter(*stars.xy_px[missed].T, s=40, marker="+", color="#ffd84d", linewidths=0.8,
               label=f"catalog star not detected ({len(missed)}: blended with a neighbour or faint)")
    for k in range(min(8, len(stars))):
        x, y = stars.xy_px[k]
        ax.annotate(f"HIP {stars.hip[k]}  Hp {stars.mag[k]:.1f}", (x, y), xytext=(9, -9),
                    textcoords="offset points", color="#9ad0ff", fontsize=7.5)
    ax.set_xlim(-0.5, frame.camera.width_px - 0.5)
    ax.set_ylim(frame.camera.height_px - 0.5, -0.5)
    ax.set_xticks([])
    ax.set_yticks([])
    handles, labels = ax.get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper left", bbox_to_anchor=(0.665, 0.47), fontsize=9, frameon=False)
    err = dist[ok]
    fig.text(0.665, 0.975, f"Simulated A1 frame, seed 000 dock (Jiangyin)\n{frame.utc_iso}, heading "
             f"{HEADING_DEG:.4f} deg, level\n{len(stars)} catalog stars (Hp <= {frame.mag_limit:g})",
             fontsize=12, va="top")
    _zoom(fig, frame, ext, stars)
    fig.text(0.665, 0.03, _caption(frame, ext, ok, err), fontsize=9, va="bottom", family="monospace")
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    plt.close(fig)


def _zoom(fig, frame, ext, stars):
    """Pixel-level view around the brightest unsaturated star with its truth and centroid."""
    k = int(np.argmax(stars.signal_e < 0.5 * frame.camera.full_well_e / 0.22))
    x, y = stars.xy_px[k]
    half = 7
    x0, y0 = int(round(x)) - half, int(round(y)) - half
    cut = frame.image[max(y0, 0):y0 + 2 * half + 1, max(x0, 0):x0 + 2 * half + 1].astype(float)
    ax = fig.add_axes([0.69, 0.50, 0.24, 0.33])
    ax.imshow(cut, cmap="magma", origin="upper", interpolation="nearest",
              extent=(x0 - 0.5, x0 + cut.shape[1] - 0.5, y0 + cut.shape[0] - 0.5, y0 - 0.5))
    ax.plot(x, y, "+", color="cyan", ms=14, mew=1.5, label="truth (mid-exposure)")
    near = np.argmin(np.hypot(*(ext.xy_px - [x, y]).T))
    ax.plot(*ext.xy_px[near], "x", color="lime", ms=10, mew=1.5, label="extracted centroid")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(f"HIP {stars.hip[k]} (Hp {stars.mag[k]:.2f}), pixels in ADU", fontsize=9)
    ax.tick_params(labelsize=7)


def _caption(frame, ext, ok, err) -> str:
    cam, s = frame.camera, frame.ship
    rho = frame.stars.refraction_rad * 206264.806
    return "\n".join([
        f"camera {cam.name}: {cam.width_px}x{cam.height_px} px, f = {cam.f_mm} mm,",
        f"  {cam.pixel_scale_arcsec:.2f}''/px, PSF sigma {cam.psf_sigma_px} px, {cam.exposure_s * 1e3:.0f} ms, 12-bit",
        f"installed az {s.install_az_rad * 57.29578:.4f} el {s.install_el_rad * 57.29578:.4f} deg",
        f"weather {frame.weather.pressure_hpa} hPa, {frame.weather.temperature_c} C;",
        f"  refraction per star {rho.min():.1f}..{rho.max():.1f}'' ({frame.refraction_model})",
        "noise: shot, read, dark, sky, hot pixels;",
        "false objects: 1 satellite trail, 6 cosmic rays",
        "",
        f"extracted {len(ext.xy_px)}: {ok.sum()} matched within {MATCH_RADIUS_PX} px",
        f"centroid - truth: median {np.median(err):.3f} px,",
        f"  RMS {np.sqrt(np.mean(err ** 2)):.3f} px over matched stars",
        f"seed {frame.seed}",
    ])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("a1_frame.png"))
    args = parser.parse_args()
    frame = simulate()
    ext = extract_stars(frame.image, gain_e_per_adu=frame.camera.gain_e_per_adu)
    draw(frame, ext, args.out)
    print(f"wrote {args.out}: {len(frame.stars)} catalog stars, {len(ext.xy_px)} extracted")


if __name__ == "__main__":
    main()
