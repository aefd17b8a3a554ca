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

Smeared frames (``--rates``, deg/s): the same kind of scene on sensor A1 turning about
an axis with a large boresight component (field rotation, as for A1 on a rolling ship)
during its 80 ms exposure. Completeness is over stars with a line-integrated SNR >= 10
(the flux SNR of the smeared PSF's Fisher information, unknowns x, y, flux, background);
the errors are split along and across each star's smear and divided by its bound.
"shipstar" estimates the smear from the frame; "shipstar+hint" is given the camera's PSF
and gain and the frame's median smear (the pipeline knows the rate); sep runs with its
default 3x3 filter (threshold 2.5) and with a line kernel along the smear (the smeared
PSF; threshold 1.5, the best completeness for ~2 false detections per frame; its
centroids: the isophotal first moments, ``objs["x"], objs["y"]``; ``winpos`` is for
round stars). The ratio to the bound is an RMS over both frames' SNR >= 10 stars: a
single faint star found 5 sigma off counts.

Rendering: ``render_frame`` (exact: the background pixels drawn from their exact ADU
distribution by a table look-up, the star pixels through the Poisson + read-noise chain)
against the plain numpy chain on every pixel (``rng.poisson`` of the expected image,
``rng.standard_normal``, ADC), on the same unsmeared and smeared A1 scenes.

Then, if the folder of real photographs exists, shipstar against cedar-solve's
centroider (``tetra3.get_centroids_from_image``, an independent extractor) on them:
counts, time, and how many of cedar-solve's 30 brightest centroids shipstar finds
within 2 px.

Run: ``python benchmarks/bench_extract.py [--frames N] [--seed S] [--rates 1,2,4] [--real DIR]``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")          # one core, as the pipeline runs (and the targets are set)

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402

import numpy as np  # noqa: E402
from scipy.special import erf  # noqa: E402

from shipstar.camera import camera_preset  # noqa: E402
from shipstar.extract import FLAG_SATURATED, extract_stars  # noqa: E402
from shipstar.simulate._render import FalseObjects, render_frame, render_image_e, star_signal_e  # noqa: E402

MATCH_PX = 1.0
ISOLATION_PX = 12.0


#: Rotation axis of the smeared frames, sensor axes (X boresight).
SMEAR_AXIS = np.array([0.76, 0.52, 0.39]) / np.linalg.norm([0.76, 0.52, 0.39])


def scene(camera, rng):
    """Star positions (N, 2), signals (N,) and false objects of one frame."""
    n = int(rng.integers(30, 61))
    u = rng.uniform(size=n)
    lo, hi, slope = 3.0, 8.8, 0.45 * np.log(10.0)
    mag = np.log(np.exp(slope * lo) + u * (np.exp(slope * hi) - np.exp(slope * lo))) / slope
    xy = rng.uniform([3.0, 3.0], [camera.width_px - 4.0, camera.height_px - 4.0], size=(n, 2))
    return xy, star_signal_e(camera, mag), FalseObjects(cosmic_ray_count=int(rng.integers(0, 4)))


def simulate(camera, rng):
    """One frame and its truth: (image, xy_px (N, 2), signal_e (N,))."""
    xy, signal, fo = scene(camera, rng)
    image = render_frame(camera, xy, signal, rng, false_objects=fo)
    return image, xy, signal


def smear_of(camera, xy, rate_deg_s):
    """Smear vectors (N, 2) of stars at ``xy`` for the sensor turning at ``rate_deg_s`` about SMEAR_AXIS."""
    from shipstar.simulate import smear_px_from_rate

    return smear_px_from_rate(camera, camera.unproject(xy), SMEAR_AXIS * np.radians(rate_deg_s), camera.exposure_s)


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
    names = ("x_centroid", "y_centroid") if "x_centroid" in found.colnames else ("xcentroid", "ycentroid")
    x0, y0 = (np.asarray(found[n]) for n in names)       # photutils >= 3 renamed them (the old names warn)
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


# ---------------------------------------------------------------- smeared frames

def smeared_bound(camera, signal_e, xy_px, smear_px):
    """(covariance (2, 2) of x, y; line-integrated flux SNR) of one smeared star (Fisher information)."""
    s = camera.psf_sigma_px
    n = max(1, int(np.ceil(np.hypot(*smear_px) / (0.1 * s))))
    t = (np.arange(n) + 0.5) / n - 0.5
    half = [int(np.ceil(abs(d) / 2 + 5 * s)) + 2 for d in smear_px]

    def profile(c, d, h):
        u = (np.rint(c) + np.arange(-h, h + 2) - 0.5)[None, :] - (c + t * d)[:, None]
        cdf = 0.5 * erf(u / (np.sqrt(2) * s))
        pdf = np.exp(-0.5 * (u / s) ** 2) / (np.sqrt(2 * np.pi) * s)
        return np.diff(cdf, axis=1), -np.diff(pdf, axis=1)

    ex, dex = profile(xy_px[0], smear_px[0], half[0])
    ey, dey = profile(xy_px[1], smear_px[1], half[1])
    shape, d_x, d_y = ey.T @ ex / n, ey.T @ dex / n, dey.T @ ex / n
    bg_e = (camera.sky_e_per_px_per_s + camera.dark_e_per_s) * camera.exposure_s
    var = bg_e + signal_e * shape + camera.read_noise_e ** 2 + camera.gain_e_per_adu ** 2 / 12.0
    jac = np.stack([signal_e * d_x, signal_e * d_y, shape, np.ones_like(shape)], axis=-1).reshape(-1, 4)
    cov = np.linalg.inv(jac.T @ (jac / var.reshape(-1)[:, None]))
    return cov[:2, :2], signal_e / np.sqrt(cov[2, 2])


def line_kernel(smear_px, sigma_px):
    """sep filter kernel: the smeared PSF (normalised), for the line-filtered detection."""
    reach = int(np.ceil(np.abs(smear_px).max() / 2 + 3 * sigma_px))
    image = render_image_e((2 * reach + 1, 2 * reach + 1), [[reach, reach]], [1.0], sigma_px, smear_px=smear_px)
    return (image / image.max()).astype(np.float32)


def run_sep_smeared(image, kernel):
    import sep

    data = image.astype(np.float32)
    bkg = sep.Background(data, bw=64, bh=64)
    sub = data - bkg.back()
    if kernel is None:
        objs = sep.extract(sub, 2.5, err=bkg.globalrms, minarea=3)
    else:
        objs = sep.extract(sub, 1.5, err=bkg.globalrms, minarea=5, filter_kernel=kernel)
    return np.stack([objs["x"], objs["y"]], axis=1)


def smeared_scores(found_xy, xy, smear, covs, snr):
    """Matches within 1 px + 4 bound (one to one): hits, false, errors over the bound along and across."""
    radius = 1.0 + 4.0 * np.sqrt(np.trace(covs, axis1=1, axis2=2))
    hit = np.zeros(len(xy), dtype=bool)
    ratios, false = [], len(found_xy)
    if len(found_xy):
        d = np.linalg.norm(found_xy[:, None] - xy[None], axis=2)
        used = np.zeros(len(found_xy), dtype=bool)
        for f, t in zip(*np.unravel_index(np.argsort(d, axis=None), d.shape)):
            if d[f, t] > radius[t] or used[f] or hit[t]:
                continue
            used[f] = hit[t] = True
            if snr[t] >= 10:
                u = smear[t] / np.hypot(*smear[t])
                for axis in (u, np.array([-u[1], u[0]])):
                    ratios.append((found_xy[f] - xy[t]) @ axis / np.sqrt(axis @ covs[t] @ axis))
        false = int(np.sum(~used))
    return hit, false, np.array(ratios).reshape(-1, 2)


def smeared_benchmark(camera, rates, frames, seed):
    print(f"\nsmeared frames: sensor A1 turning about {np.round(SMEAR_AXIS, 2)} (sensor axes), {frames} frames per rate")
    print(f"{'rate':>5s} {'L px':>5s} {'method':14s} {'ms/frame':>9s} {'x shipstar':>10s} {'SNR>=10':>8s} "
          f"{'false/fr':>8s} {'along/bd':>8s} {'across/bd':>9s}")
    for rate in rates:
        rng = np.random.default_rng(seed + int(100 * rate))
        stats = {}
        for _ in range(frames):
            xy, signal, fo = scene(camera, rng)
            smear = smear_of(camera, xy, rate)
            image = render_frame(camera, xy, signal, rng, smear_px=smear, false_objects=fo)
            covs, snr = map(np.array, zip(*(smeared_bound(camera, f, p, d) for f, p, d in zip(signal, xy, smear))))
            hint = np.median(smear, axis=0)
            kernel = line_kernel(hint, camera.psf_sigma_px)
            methods = {
                "shipstar": lambda: extract_stars(image).xy_px,
                "shipstar+hint": lambda: extract_stars(image, psf_sigma_px=camera.psf_sigma_px,
                                                       gain_e_per_adu=camera.gain_e_per_adu, smear_px=hint).xy_px,
                "sep": lambda: run_sep_smeared(image, None),
                "sep+line": lambda: run_sep_smeared(image, kernel),
            }
            for name, fn in methods.items():
                fn()
                t0 = time.perf_counter()
                found = fn()
                dt = time.perf_counter() - t0
                hit, false, ratios = smeared_scores(found, xy, smear, covs, snr)
                st = stats.setdefault(name, dict(t=[], hit10=[], false=0, ratios=[]))
                st["t"].append(dt)
                st["hit10"].append(hit[snr >= 10])
                st["false"] += false
                st["ratios"].append(ratios)
        length = np.median(np.hypot(*smear.T))
        t_ship = np.median(stats["shipstar"]["t"])
        for name, st in stats.items():
            r = np.concatenate(st["ratios"])
            rms = np.sqrt(np.mean(r ** 2, axis=0)) if len(r) else (np.nan, np.nan)
            t = np.median(st["t"])
            print(f"{rate:5.1f} {length:5.1f} {name:14s} {1e3 * t:9.1f} {t / t_ship:10.2f} "
                  f"{np.mean(np.concatenate(st['hit10'])):8.3f} {st['false'] / frames:8.2f} {rms[0]:8.2f} {rms[1]:9.2f}")


# ---------------------------------------------------------------- rendering

# ---------------------------------------------------------------- at sea

def best_time(fn, repeat=3):
    """(result, best wall time of ``repeat`` runs after a warm-up)."""
    out = fn()
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return out, best


def sea_benchmark(frames, seed):
    """Sensor A1 on the ship at sea, as the pipeline sees it: ``simulate._session.sea_session``."""
    from shipstar.simulate._session import _sensor_frame, sea_session

    spec = sea_session(seed=seed)
    sensor = spec.sensors[0]
    times = spec.times_s(sensor)
    picks = np.linspace(0, min(len(times), 80) - 1, frames).round().astype(int)     # over one 8 s roll period
    print(f"\nA1 sea frame, 10 ms exposure, ship rolling 5 deg/8 s (sea_session: pitch 2 deg/6 s, curved "
          f"paths), {frames} frames over a roll period")
    stats, lengths = {}, []
    for k in picks:
        frame = _sensor_frame(spec, sensor, int(k), float(times[k]))
        camera, stars, image = frame.camera, frame.stars, frame.image
        smear = stars.smear_px
        lengths.append(float(np.median(np.hypot(*smear.T))))
        covs, snr = map(np.array, zip(*(smeared_bound(camera, f, p, d)
                                        for f, p, d in zip(stars.signal_e, stars.xy_px, smear))))
        cam = dict(psf_sigma_px=camera.psf_sigma_px, gain_e_per_adu=camera.gain_e_per_adu)
        methods = {
            "shipstar (pipeline call: PSF, gain)": lambda: extract_stars(image, **cam).xy_px,
            "shipstar+hint (PSF, gain, smear)": lambda: extract_stars(image, smear_px=np.median(smear, axis=0),
                                                                      **cam).xy_px,
            "sep (3x3 filter)": lambda: run_sep_smeared(image, None),
        }
        for name, fn in methods.items():
            found, dt = best_time(fn)
            hit, false, ratios = smeared_scores(found, stars.xy_px, smear, covs, snr)
            st = stats.setdefault(name, dict(t=[], hit10=[], false=0, ratios=[]))
            st["t"].append(dt)
            st["hit10"].append(hit[snr >= 10])
            st["false"] += false
            st["ratios"].append(ratios)
    print(f"median smear per frame {min(lengths):.1f}-{max(lengths):.1f} px; load average {os.getloadavg()[0]:.2f}")
    print(f"{'method':36s} {'ms/frame':>8s} {'max ms':>7s} {'x shipstar':>10s} {'SNR>=10':>8s} {'false/fr':>8s} "
          f"{'along/bd':>8s} {'across/bd':>9s}")
    t_ship = np.median(next(iter(stats.values()))["t"])
    for name, st in stats.items():
        r = np.concatenate(st["ratios"])
        rms = np.sqrt(np.mean(r ** 2, axis=0)) if len(r) else (np.nan, np.nan)
        t = np.median(st["t"])
        print(f"{name:36s} {1e3 * t:8.1f} {1e3 * max(st['t']):7.1f} {t / t_ship:10.2f} "
              f"{np.mean(np.concatenate(st['hit10'])):8.3f} {st['false'] / frames:8.2f} {rms[0]:8.2f} {rms[1]:9.2f}")


def render_brute_force(camera, xy, signal, rng, smear_px=None):
    """The plain numpy chain on every pixel: Poisson of the expected image, read noise, ADC."""
    bg = (camera.sky_e_per_px_per_s + camera.dark_e_per_s) * camera.exposure_s
    mean = render_image_e((camera.height_px, camera.width_px), xy, signal, camera.psf_sigma_px, bg,
                          smear_px=smear_px)
    electrons = np.minimum(rng.poisson(mean).astype(float), camera.full_well_e)
    electrons += camera.read_noise_e * rng.standard_normal(electrons.shape)
    adu = np.clip(np.rint(electrons / camera.gain_e_per_adu + camera.bias_adu), 0, camera.adc_max_adu)
    return adu.astype(np.uint16)


def render_benchmark(camera, frames, seed):
    print(f"\nrendering a 1024x1024 A1 frame with 60 stars: render_frame (exact, table look-up for the "
          f"background) vs the numpy chain on every pixel; {frames} frames")
    print(f"{'rate':>5s} {'render_frame ms':>16s} {'numpy chain ms':>15s} {'speed-up':>9s}")
    rng = np.random.default_rng(seed)
    xy = rng.uniform(10, 1014, size=(60, 2))
    signal = star_signal_e(camera, rng.uniform(3.0, 8.8, 60))
    for rate in (0.0, 1.0, 4.0):
        smear = smear_of(camera, xy, rate) if rate else None
        times = {"fast": [], "brute": []}
        for _ in range(frames):
            for name, fn in (("fast", lambda: render_frame(camera, xy, signal, rng, smear_px=smear,
                                                           hot_pixel_fraction=0.0)),
                             ("brute", lambda: render_brute_force(camera, xy, signal, rng, smear))):
                t0 = time.perf_counter()
                fn()
                times[name].append(time.perf_counter() - t0)
        fast, brute = np.median(times["fast"]), np.median(times["brute"])
        print(f"{rate:5.1f} {1e3 * fast:16.1f} {1e3 * brute:15.1f} {brute / fast:9.1f}")


def point_benchmark(camera, rng, methods, frames):
    """Unsmeared A1 frames: shipstar against sep and photutils."""
    stats = {m: dict(t=[], hit=[], hit10=[], false=0, ratios=[]) for m in methods}
    for _ in range(frames):
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
    print(f"{frames} frames, sensor A1 (1024x1024, 12-bit, PSF sigma {camera.psf_sigma_px} px); "
          f"load average {os.getloadavg()[0]:.2f}")
    print(f"{'method':12s} {'ms/frame':>9s} {'x shipstar':>10s} {'complete':>9s} {'SNR>=10':>8s} "
          f"{'false/fr':>8s} {'RMS/bound':>9s} {'n':>5s}")
    t_ship = np.median(stats["shipstar"]["t"])
    for name, s in stats.items():
        t = np.median(s["t"])
        ratios = np.concatenate(s["ratios"])
        rms = np.sqrt(np.mean(ratios ** 2)) if len(ratios) else float("nan")
        print(f"{name:12s} {1e3 * t:9.2f} {t / t_ship:10.2f} {np.mean(np.concatenate(s['hit'])):9.3f} "
              f"{np.mean(np.concatenate(s['hit10'])):8.3f} {s['false'] / frames:8.2f} {rms:9.3f} "
              f"{len(ratios):5d}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--rates", default="1,2,4",
                        help="comma-separated angular rates (deg/s) of the smeared frames ('' to skip)")
    parser.add_argument("--smeared-frames", type=int, default=3, help="frames per rate")
    parser.add_argument("--sea-frames", type=int, default=8, help="frames of the at-sea session (0 to skip)")
    parser.add_argument("--no-render", action="store_true", help="skip the rendering benchmark")
    parser.add_argument("--real", default="/work/shared/real-images",
                        help="folder of real JPEG frames to compare with cedar-solve (skipped if absent)")
    args = parser.parse_args(argv)
    camera = camera_preset("A1")
    rng = np.random.default_rng(args.seed)
    methods = {"shipstar": run_shipstar, "shipstar+cam": run_shipstar_camera, "sep": run_sep,
               "photutils": run_photutils}
    for name in ("sep", "photutils"):                # peers not installed: left out, and said so
        if importlib.util.find_spec(name) is None:
            print(f"{name} is not installed (pip install '.[bench]'): left out")
            methods.pop(name)
    if args.frames > 0:
        point_benchmark(camera, rng, methods, args.frames)
    if args.rates:
        smeared_benchmark(camera, [float(r) for r in args.rates.split(",")], args.smeared_frames, args.seed)
    if args.sea_frames > 0:
        sea_benchmark(args.sea_frames, args.seed)
    if not args.no_render:
        render_benchmark(camera, max(3, args.frames // 2), args.seed)
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
