"""``shipstar solve``: extract the stars of an image, identify them, fit the attitude."""

from __future__ import annotations

import argparse

from shipstar.cli._common import emit_json, finite_float, float_in_range, int_in_range, positive_float

EPILOG = """\
examples:
  shipstar solve frame.fits --camera A1
  shipstar solve night_sky.jpg --fov-deg 10 --json
  shipstar solve frame.png --camera my_camera.toml --mag-limit 7.2
  shipstar solve night1/f001.fits --camera seed002 --json > lists/f001.json   # for calibration

With --camera (a preset name or a camera TOML file) the calibrated camera model is used.
With --fov-deg the image is treated as a pinhole camera with the principal point at the
image centre and this horizontal field of view, known to +-10 % (--fov-tolerance); the
focal length and a radial distortion term are refined from the matched stars and the
solved FOV is reported.  The star database for the field is built on first use and
cached (see docs/identification.md).  roll_deg is the position angle of the image's up
direction, from celestial north through east (docs/conventions.md).

--json prints one object: solved, reason ("" when solved), ra_deg, dec_deg, roll_deg,
fov_deg, matched, rms_arcsec, time_ms, date_obs (mid-exposure UTC of a FITS image whose
header gives it: DATE-AVG, else DATE-OBS, the start, plus EXPTIME/2, or DATE-OBS itself
with --date-obs-is mid; else null), camera (null with --fov-deg), width_px, height_px and
stars [{"x_px", "y_px", "hip"}] (hip -1 when unmatched).  Saved as FILE.json, it is a
frame for 'shipstar calibrate intrinsics --frames DIR'.

exit status: 0 solved, 1 not solved (the reason is printed), 2 bad input.
"""


_fov = float_in_range(0.5, 60.0, "0.5 .. 60 deg", angle=True)
_tolerance = float_in_range(0.0, 0.5, "0 .. 0.5")
_count = int_in_range(5, 1000, "5 .. 1000")


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "solve", help="plate-solve an image: boresight RA/Dec, roll, FOV",
        description="Extract the stars of an image (FITS, PNG, TIFF, JPEG, .npy), identify "
                    "them against the Hipparcos catalog (lost-in-space) and fit the sensor "
                    "attitude in ICRS.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("image", help="image file")
    cam = p.add_mutually_exclusive_group(required=True)
    cam.add_argument("--camera", metavar="NAME|FILE", help="camera preset (A1, A2, seed002, seed004) or TOML file")
    cam.add_argument("--fov-deg", type=_fov, help="horizontal field of view of a pinhole camera (deg)")
    p.add_argument("--fov-tolerance", type=_tolerance, default=None,
                   help="relative FOV uncertainty (default 0.1 with --fov-deg, 0 with --camera)")
    p.add_argument("--mag-limit", type=finite_float, default=None,
                   help="database magnitude limit (Hp; default adapted to the field)")
    p.add_argument("--centroid-error-px", type=positive_float, default=None,
                   help="bound on a centroid's error per axis (px, default 1)")
    p.add_argument("--threshold-sigma", type=positive_float, default=5.0,
                   help="extraction detection threshold (default 5)")
    p.add_argument("--max-stars", type=_count, default=60,
                   help="brightest extracted stars used (default 60)")
    p.add_argument("--date-obs-is", choices=("start", "mid"), default="start",
                   help="what a FITS image's DATE-OBS means (default start, the FITS standard)")
    p.add_argument("--trust-flags", action="store_true",
                   help="use --camera even where the FITS header's SENSOR/INSTRUME names another sensor or camera "
                        "(recorded in the output; docs/file-formats.md, Header cross-checks)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(run=run)
    return p


def _time_line(res) -> str:
    if res.date_obs:
        return f"\nmid-exposure UTC {res.date_obs}"
    if res.time_problem:
        return f"\nno frame time: {res.time_problem}"
    return ""


def _summary(res) -> str:
    if not res.solved:
        return (f"not solved: {res.reason}\n"
                f"{len(res.xy_px)} stars extracted, {res.time_ms:.0f} ms" + _time_line(res))
    ident = res.identification
    return (f"solved: RA {res.ra_deg:.4f} deg, Dec {res.dec_deg:+.4f} deg, roll {res.roll_deg:.3f} deg, "
            f"FOV {res.fov_deg:.4f} deg\n"
            f"matched {res.matched} of {len(res.xy_px)} stars, rms {res.rms_arcsec:.1f} arcsec, "
            f"p_false {ident.p_false:.1e}, {res.time_ms:.0f} ms" + _time_line(res))


def _header_record(args) -> dict:
    """The header cross-checks of a FITS image against --camera (SENSOR/INSTRUME, image
    size): ShipstarError on a contradiction, the override record with --trust-flags."""
    from pathlib import Path

    from shipstar._fitsio import read_fits_header
    from shipstar.camera import load_camera
    from shipstar.cli._header_checks import header_check, override_record
    from shipstar.errors import ShipstarError

    if args.camera is None:
        return {}
    try:
        with open(Path(args.image), "rb") as fh:
            head = fh.read(9)
    except OSError:
        return {}                       # solve_image says why
    if head != b"SIMPLE  =" and not head.startswith(b"\x1f\x8b"):
        return {}                       # not FITS: no header to check
    try:
        info = read_fits_header(args.image, date_obs_is=args.date_obs_is)
    except ShipstarError:
        return {}                       # solve_image reads the pixels, or says why it cannot
    camera = load_camera(args.camera)
    check = header_check(args, names=(camera.name,), camera=camera, given_name=f"--camera {args.camera}")
    check(info)
    return override_record([check])


def run(args) -> int:
    from shipstar.cli._header_checks import print_overrides
    from shipstar.identify import solve_image

    record = _header_record(args)
    print_overrides("solve", record)
    res = solve_image(args.image, camera=args.camera, fov_deg=args.fov_deg,
                      fov_tolerance=args.fov_tolerance, mag_limit=args.mag_limit,
                      centroid_error_px=args.centroid_error_px,
                      threshold_sigma=args.threshold_sigma, max_stars=args.max_stars,
                      date_obs_is=args.date_obs_is)
    if args.json:
        emit_json({**res.as_json_dict(), **record})
    else:
        print(_summary(res) + ("\n--trust-flags: the camera was used as given" if record else ""))
    return 0 if res.solved else 1
