"""``shipstar extract FRAME``: find the stars in one frame and print their centroids."""

from __future__ import annotations

import argparse
import math
import sys

from shipstar.cli._common import emit_json, finite_float, int_in_range

EPILOG = """\
example:
  shipstar extract frame_0001.fits --json
  shipstar extract sky.jpg --max-stars 20 --threshold-sigma 6
  shipstar extract frame.fits --camera A1          # PSF sigma, gain, saturation from the camera
  shipstar extract sea.fits --camera A1 --smear-px 18.5 -6.0   # streaks: the smear vector, if known

Prints one line per star, brightest first (x right, y down, centre of the top-left
pixel = (0, 0)); with --json exactly one JSON object:
  {"stars": [{"x_px", "y_px", "flux_adu", "peak_adu", "snr", "npix", "xy_sigma_px",
              "flags": ["saturated", "edge", "fit_failed", "elongated"]}, ...],
   "background_adu", "noise_adu", "psf_sigma_px", "smear_px": [dx, dy],
   "image": {"path", "width_px", "height_px"}}
Stars smeared by the ship's motion (streaks) are found and centred at mid-exposure; the
smear is estimated from the frame unless --smear-px gives it.
Exit status: 0 stars found, 1 no star found (the frame is readable but empty),
2 bad input (unreadable file, bad option).
"""


_positive_int = int_in_range(1)


def register(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "extract",
        help="find stars in a frame (FITS, PNG, TIFF, JPEG, .npy) and measure their centroids",
        description="Find the stars in one frame and measure their sub-pixel centroids.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("frame", metavar="FRAME", help="image file: FITS, PNG, TIFF, JPEG or .npy")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--threshold-sigma", type=finite_float, default=5.0, metavar="S",
                        help="detection threshold in noise sigmas of a 3x3 sum (default 5)")
    parser.add_argument("--max-stars", type=_positive_int, default=None, metavar="N",
                        help="keep the N brightest stars")
    parser.add_argument("--refine", choices=("gaussian", "none"), default="gaussian",
                        help="centroid: Gaussian PSF fit (default) or centre of gravity")
    parser.add_argument("--camera", default=None, metavar="NAME|FILE",
                        help="camera preset or TOML file: its PSF sigma, gain and saturation level")
    parser.add_argument("--psf-sigma-px", type=finite_float, default=None, metavar="S",
                        help="PSF sigma (default: the camera's, else fitted on the brightest stars)")
    parser.add_argument("--gain-e-per-adu", type=finite_float, default=None, metavar="G",
                        help="gain (default: the camera's, else estimated from the stars)")
    parser.add_argument("--saturation-adu", type=finite_float, default=None, metavar="A",
                        help="saturation level (default: the camera's, else the top of the ADC range)")
    parser.add_argument("--smear-px", type=finite_float, nargs=2, default=None, metavar=("DX", "DY"),
                        help="motion smear of the stars during the exposure (px; default: estimated)")
    parser.set_defaults(run=run)
    return parser


def _camera_options(args):
    """PSF sigma, gain and saturation: explicit flags first, then the camera, else None."""
    psf, gain, sat = args.psf_sigma_px, args.gain_e_per_adu, args.saturation_adu
    if args.camera is not None:
        from shipstar.camera import load_camera

        cam = load_camera(args.camera)
        psf = cam.psf_sigma_px if psf is None else psf
        gain = cam.gain_e_per_adu if gain is None else gain
        if sat is None:
            sat = min(float(cam.adc_max_adu), cam.full_well_e / cam.gain_e_per_adu + cam.bias_adu)
    return psf, gain, sat


def _number(value):
    value = float(value)
    return value if math.isfinite(value) else None


def _as_json(result, path) -> dict:
    from shipstar.extract import flag_names

    stars = [
        {"x_px": float(x), "y_px": float(y), "flux_adu": float(f), "peak_adu": float(p), "snr": _number(s),
         "npix": int(n), "xy_sigma_px": _number(e), "flags": flag_names(fl)}
        for (x, y), f, p, s, n, e, fl in zip(result.xy_px, result.flux_adu, result.peak_adu, result.snr,
                                             result.npix, result.xy_sigma_px, result.flags)
    ]
    height, width = result.shape_hw
    return {"stars": stars, "background_adu": result.background_adu, "noise_adu": result.noise_adu,
            "psf_sigma_px": _number(result.psf_sigma_px),
            "smear_px": [float(v) for v in result.smear_px],
            "image": {"path": str(path), "width_px": int(width), "height_px": int(height)}}


def _print_table(result, path) -> None:
    from shipstar.extract import flag_names

    height, width = result.shape_hw
    print(f"{path}: {width}x{height} px, background {result.background_adu:.2f} ADU, "
          f"noise {result.noise_adu:.2f} ADU, PSF sigma {result.psf_sigma_px:.2f} px, {len(result)} stars")
    print(f"{'#':>4} {'x_px':>9} {'y_px':>9} {'flux_adu':>11} {'peak_adu':>9} {'snr':>8} {'npix':>5}  flags")
    for i, ((x, y), f, p, s, n, fl) in enumerate(zip(result.xy_px, result.flux_adu, result.peak_adu,
                                                     result.snr, result.npix, result.flags)):
        print(f"{i:4d} {x:9.3f} {y:9.3f} {f:11.1f} {p:9.1f} {s:8.1f} {n:5d}  {','.join(flag_names(fl))}")


def run(args) -> int:
    from shipstar.extract import extract_stars, read_image

    psf, gain, sat = _camera_options(args)
    image = read_image(args.frame)
    result = extract_stars(image, threshold_sigma=args.threshold_sigma, max_stars=args.max_stars,
                           refine=args.refine, psf_sigma_px=psf, gain_e_per_adu=gain, saturation_adu=sat,
                           smear_px=args.smear_px)
    if args.json:
        emit_json(_as_json(result, args.frame))
    else:
        _print_table(result, args.frame)
    if len(result) == 0:
        print(f"shipstar extract: no stars found in {args.frame} "
              f"(noise {result.noise_adu:.3g} ADU; try a lower --threshold-sigma)", file=sys.stderr)
        return 1
    return 0
