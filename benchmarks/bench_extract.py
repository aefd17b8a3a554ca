"""Star extraction: shipstar against sep and photutils on the same simulated frames.

Frames: sensor A1 (``camera_preset("A1")``: 1024x1024, 12-bit, PSF sigma 0.8 px, read
noise 20 e, gain 25 e/ADU), 30-60 stars with magnitudes drawn from N(<m) ~ 10**(0.45 m)
over 3..8.8, the preset's hot pixels and a few cosmic rays. Truth is known, so for each
extractor the script prints

- time per frame (whole pipeline: background, detection, centroids), and its ratio to
  shipstar's;
- completeness: true stars found within 1 px, over all stars and over those with a
  Cramer-Rao SNR >= 10;
- false detections per frame (nothing true within 1 px);
- centroid error as a multiple of the Cramer-Rao bound: sqrt(mean((err / bound)**2))
  over both axes of the found, unsaturated, isolated stars with SNR >= 10. The bound is
  the Fisher information of the pixel-integrated Gaussian with Poisson + read + ADC
  noise, unknowns x, y, flux, background (computed here, independently of shipstar).

Anchors: sep (``sep.Background``, ``sep.extract`` with its 3x3 matched filter,
``sep.winpos`` windowed centroids with sig = 2/2.35 x half-light radius) and photutils
(``sigma_clipped_stats``, ``DAOStarFinder``, ``centroid_sources`` with
``centroid_2dg``). Thresholds were set so that each finds the faint stars with few
false detections (sep: 2.5 sigma in the filtered image, minarea 3; DAOStarFinder:
5 sigma, below which its false detections explode). "shipstar+cam" is shipstar given
the camera's PSF sigma and gain, as the pipeline calls it.

Then, if the folder of real photographs exists, shipstar against cedar-solve's
centroider (``tetra3.get_centroids_from_image``, an independent extractor) on them:
counts, time, and how many of cedar-solve's 30 brightest centroids shipstar finds
within 2 px.

Run: ``python benchmarks/bench_extract.py [--frames N] [--seed S] [--real DIR]``.
"""

from __future__ import annotations

import argparse
import os
import time
import warnings

import numpy as np
from scipy.special import erf

from shipstar.camera import camera_preset
from shipstar.extract import FLAG_SATURATED, extract_stars
from shipstar.simulate._render import FalseObjects, render_frame, star_signal_e

MATCH_PX = 1.0
ISOLATION_PX = 12.0


def simulate(camera, rng):
    """One frame and its truth: (image, xy_px (N, 2), signal_e (N,))."""
    n = int(rng.integers(30, 61))
    u = rng.uniform(size=n)
    lo, hi, slope = 3.0, 8.8, 0.45 * np.log(10.0)
    mag = np.log(np.exp(slope * lo) + u * (np.exp(slope * hi) - np.exp(slope * lo))) / slope
    xy = rng.uniform([3.0, 3.0], [camera.width_px - 4.0, camera.height_px - 4.0], size=(n, 2))
    signal = star_signal_e(camera, mag)
    fo = FalseObjects(cosmic_ray_count=int(rng.integers(0, 4)))
    image = render_frame(camera, xy, signal, rng, false_objects=fo)
    return image, xy, signal


def bound_px(camera, signal_e, xy_px, half=8):
    """Cramer-Rao bound on x per star (pixel-integrated Gaussian, Poisson + read + ADC noise)."""
    s = camera.psf_sigma_px
    bg_e = (camera.sky_e_per_px_per_s + camera.dark_e_per_s) * camera.exposure_s
    floor = camera.read_noise_e ** 2 + camera.gain_e_per_adu ** 2 / 12.0
    out = np.empty(len(signal_e))
    k = np.arange(-half, half + 2) - 0.5
    for i, (flux, (x, y)) in enumerate(zip(signal_e, xy_px)):
        def prof(c):
            u = k - (c - np.rint(c))
            return np.diff(0.5 * erf(u / (np.sqrt(2) * s))), -np.diff(np.exp(-0.5 * (u / s) ** 2) / (np.sqrt(2 * np.pi) * s))
        ex, dex = prof(x)
        ey, dey = prof(y)
        mu = bg_e + flux * np.outer(ey, ex)
        jac = np.stack([flux * np.outer(ey, dex), flux * np.outer(dey, ex), np.outer(ey, ex),
                        np.ones_like(mu)], axis=-1).reshape(-1, 4)
        info = jac.T @ (jac / (mu + floor).reshape(-1)[:, None])
        out[i] = np.sqrt(np.linalg.inv(info)[0, 0])
    return out


def snr_of(camera, signal_e):
    """Cramer-Rao SNR of the flux of a centred star."""
    s = camera.psf_sigma_px
    k = np.arange(-8, 10) - 0.5
    e = np.diff(0.5 * erf(k / (np.sqrt(2) * s)))
    shape = np.outer(e, e).reshape(-1)
    bg_e = (camera.sky_e_per_px_per_s + camera.dark_e_per_s) * camera.exposure_s
    floor = camera.read_noise_e ** 2 + camera.gain_e_per_adu ** 2 / 12.0
    out = []
    for flux in signal_e:
        jac = np.stack([shape, np.ones_like(shape)], axis=1)
        info = jac.T @ (jac / (bg_e + floor + flux * shape)[:, None])
        out.append(flux / np.sqrt(np.linalg.inv(info)[0, 0]))
    return np.array(out)


def run_shipstar(image, camera):
    ex = extract_stars(image)
    return ex.xy_px, (ex.flags & FLAG_SATURATED) != 0


def run_shipstar_camera(image, camera):
    ex = extract_stars(image, psf_sigma_px=camera.psf_sigma_px, gain_e_per_adu=camera.gain_e_per_adu)
    return ex.xy_px, (ex.flags & FLAG_SATURATED) != 0


def run_sep(image, camera):
    import sep

    data = image.astype(np.float32)
    bkg = sep.Background(data, bw=32, bh=32)
    sub = data - bkg.back()
    objs = sep.extract(sub, 2.5, err=bkg.globalrms, minarea=3)
    x, y = objs["x"], objs["y"]
    radius, _ = sep.flux_radius(sub, x, y, 6.0 * objs["a"], 0.5, normflux=objs["flux"], subpix=5)
    xw, yw, _ = sep.winpos(sub, x, y, 2.0 / 2.35 * np.maximum(radius, 0.5))
    return np.stack([xw, yw], axis=1), objs["peak"] + np.median(bkg.back()) >= camera.adc_max_adu


def run_photutils(image, camera):
    from astropy.stats import sigma_clipped_stats
    from photutils.centroids import centroid_2dg, centroid_sources
    from photutils.detection import DAOStarFinder

    data = image.astype(float)
    _, median, std = sigma_clipped_stats(data, sigma=3.0)
    sub = data - median
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        found = DAOStarFinder(fwhm=2.355 * camera.psf_sigma_px, threshold=5.0 * std)(sub)
    if found is None:
        return np.zeros((0, 2)), np.zeros(0, dtype=bool)
    x0, y0 = np.asarray(found["xcentroid"]), np.asarray(found["ycentroid"])
    inside = (x0 >= 0) & (x0 <= data.shape[1] - 1) & (y0 >= 0) & (y0 <= data.shape[0] - 1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                  # "fit may not have converged" on faint stars
        x, y = centroid_sources(sub, x0[inside], y0[inside], box_size=7, centroid_func=centroid_2dg)
    xy = np.stack([x, y], axis=1)
    good = np.all(np.isfinite(xy), axis=1)
    return xy[good], (np.asarray(found["peak"])[inside] + median >= camera.adc_max_adu)[good]


def score(found_xy, saturated, true_xy, true_snr, crb, isolated):
    """Matches within MATCH_PX (nearest, one-to-one by distance): per-frame statistics."""
    if len(found_xy) == 0:
        return dict(hit=np.zeros(len(true_xy), bool), false=0, ratios=np.zeros((0, 2)))
    d = np.linalg.norm(found_xy[:, None, :] - true_xy[None, :, :], axis=2)
    hit = np.zeros(len(true_xy), dtype=bool)
    used = np.zeros(len(found_xy), dtype=bool)
    ratios = []
    for f, t in zip(*np.unravel_index(np.argsort(d, axis=None), d.shape)):
        if d[f, t] > MATCH_PX:
            break
        if used[f] or hit[t]:
            continue
        used[f] = hit[t] = True
        if true_snr[t] >= 10 and isolated[t] and not saturated[f]:
            ratios.append((found_xy[f] - true_xy[t]) / crb[t])
    return dict(hit=hit, false=int(np.sum(~used)), ratios=np.array(ratios).reshape(-1, 2))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--real", default="/work/shared/real-images",
                        help="folder of real JPEG frames to compare with cedar-solve (skipped if absent)")
    args = parser.parse_args(argv)
    camera = camera_preset("A1")
    rng = np.random.default_rng(args.seed)
    methods = {"shipstar": run_shipstar, "shipstar+cam": run_shipstar_camera, "sep": run_sep,
               "photutils": run_photutils}
    stats = {m: dict(t=[], hit=[], hit10=[], false=0, ratios=[]) for m in methods}
    for _ in range(args.frames):
        image, xy, signal = simulate(camera, rng)
        snr = snr_of(camera, signal)
        crb = bound_px(camera, signal, xy)
        dist = np.linalg.norm(xy[:, None] - xy[None], axis=2) + np.eye(len(xy)) * 1e9
        isolated = dist.min(axis=1) > ISOLATION_PX
        for name, fn in methods.items():
            fn(image, camera)                            # warm-up (imports, caches)
            t0 = time.perf_counter()
            found, sat = fn(image, camera)
            stats[name]["t"].append(time.perf_counter() - t0)
            r = score(found, sat, xy, snr, crb, isolated)
            stats[name]["hit"].append(r["hit"])
            stats[name]["hit10"].append(r["hit"][snr >= 10])
            stats[name]["false"] += r["false"]
            stats[name]["ratios"].append(r["ratios"])
    print(f"{args.frames} frames, sensor A1 (1024x1024, 12-bit, PSF sigma {camera.psf_sigma_px} px); "
          f"load average {os.getloadavg()[0]:.2f}")
    print(f"{'method':12s} {'ms/frame':>9s} {'x shipstar':>10s} {'complete':>9s} {'SNR>=10':>8s} "
          f"{'false/fr':>8s} {'RMS/bound':>9s} {'n':>5s}")
    t_ship = np.median(stats["shipstar"]["t"])
    for name, s in stats.items():
        t = np.median(s["t"])
        ratios = np.concatenate(s["ratios"])
        rms = np.sqrt(np.mean(ratios ** 2)) if len(ratios) else float("nan")
        print(f"{name:12s} {1e3 * t:9.2f} {t / t_ship:10.2f} {np.mean(np.concatenate(s['hit'])):9.3f} "
              f"{np.mean(np.concatenate(s['hit10'])):8.3f} {s['false'] / args.frames:8.2f} {rms:9.3f} "
              f"{len(ratios):5d}")

    if args.real and os.path.isdir(args.real):
        real_images(args.real)


def real_images(folder):
    """Real photographs: shipstar against cedar-solve's centroider (tetra3.get_centroids_from_image)."""
    import glob

    from PIL import Image

    from shipstar.extract import read_image

    try:
        from tetra3 import get_centroids_from_image
    except ImportError:
        print("(cedar-solve not installed: real-image comparison skipped)")
        return
    print(f"\nreal photographs in {folder}: shipstar vs cedar-solve get_centroids_from_image")
    print(f"{'file':22s} {'shipstar n':>10s} {'ms':>6s} {'cedar n':>8s} {'ms':>6s} {'cedar top-30 found':>19s}")
    for path in sorted(glob.glob(os.path.join(folder, "*.jpg"))):
        image = read_image(path)
        extract_stars(image)
        t0 = time.perf_counter()
        ex = extract_stars(image)
        t_ship = time.perf_counter() - t0
        pil = Image.open(path)
        t0 = time.perf_counter()
        cedar = np.asarray(get_centroids_from_image(pil)).reshape(-1, 2)[:, ::-1]   # (y, x) -> (x, y)
        t_cedar = time.perf_counter() - t0
        top = cedar[:30]
        found = (np.linalg.norm(top[:, None] - ex.xy_px[None], axis=2).min(axis=1) < 2.0).sum() if len(ex) else 0
        print(f"{os.path.basename(path):22s} {len(ex):10d} {1e3 * t_ship:6.1f} {len(cedar):8d} "
              f"{1e3 * t_cedar:6.1f} {found:>13d} / {len(top)}")


if __name__ == "__main__":
    main()
