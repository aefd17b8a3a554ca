"""``shipstar solve``: extract the stars of an image, identify them, fit the attitude."""

from __future__ import annotations

import argparse
from pathlib import Path

from shipstar.cli._common import emit_json, finite_float, float_in_range, int_in_range, positive_float

EPILOG = """\
examples:
  shipstar solve night_sky.jpg                          # blind: no field of view given
  shipstar solve night_sky.jpg --fov-deg 10 --json
  shipstar solve frame.fits --camera A1 --wcs-out frame_wcs.fits
  shipstar solve photo.jpg --wcs-header photo.wcs       # sidecar: the WCS header only
  shipstar solve --centroids stars.csv --image-size-px 1920x1080 --fov-deg 20
  shipstar solve --track f001.fits f002.fits f003.fits --camera seed002 --json
  shipstar solve night1/f001.fits --camera seed002 --json > lists/f001.json   # for calibration

With --camera (a preset name or a camera TOML file) the calibrated camera model is used.
With --fov-deg the image is treated as a pinhole camera with the principal point at the
image centre and this horizontal field of view, known to +-10 % (--fov-tolerance); with
neither the field of view is searched blind: the image's short side 3.4 .. 31.5 deg
(horizontal 3.4 .. 31.5 deg for a square image, 4.5 .. 42 deg for 4:3; aspect ratios up
to 2:1).  The focal length and a radial distortion term are refined from the matched
stars and the solved FOV is reported.  A few star databases, one per field-of-view band,
are built on first use and cached ('shipstar cache info'; docs/solve.md).  roll_deg is
the position angle of the image's up direction, from celestial north through east
(docs/conventions.md).

--centroids: the inputs are text/CSV files of star centroids, one star a line:
x_px,y_px[,flux] (0-based pixels, top-left pixel centre (0, 0); commas or blanks; lines
starting with # are skipped; a header line names the columns, x_px, y_px and flux in
any order), brightest first unless a flux column is given; --image-size-px WxH gives
the image size, and a centroid outside it is an error.

--track: the inputs are a sequence (images or centroid files) of one camera: the first
is solved lost-in-space, each next one by tracking from the previous attitude
(--prior-error-deg), lost-in-space again when tracking fails.

--wcs-out FILE writes a FITS copy of the image with its WCS (TAN; TAN-SIP with the
fitted radial term or the camera's distortion) and the quaternion; --wcs-header FILE
writes the header alone as text, one 80-character card a line (astropy's
Header.fromtextfile reads it; not a FITS file).

--json prints one object per input: solved, reason ("" when solved), ra_deg, dec_deg,
roll_deg, fov_deg, matched, rms_arcsec, p_false (the false-match probability bound, 1
when not solved), q_icrs_from_sensor_wxyz (the attitude, scalar first: rotates sensor-
frame vectors into ICRS; null when not solved), fov_search (camera, hint, blind,
tracking), time_ms, date_obs (mid-exposure UTC of a FITS image whose header gives it:
DATE-AVG, else DATE-OBS, the start, plus EXPTIME/2, or DATE-OBS itself with
--date-obs-is mid; else null), camera (null without --camera), width_px, height_px and
stars [{"x_px", "y_px", "hip"}] (hip -1 when unmatched); with several inputs also
"input" (the file).  Saved as FILE.json, it is a frame for 'shipstar calibrate
intrinsics --frames DIR'.

exit status: 0 solved (every input), 1 not solved (the reason is printed), 2 bad input.
"""


_fov = float_in_range(0.5, 60.0, "0.5 .. 60 deg", angle=True)
_tolerance = float_in_range(0.0, 0.5, "0 .. 0.5")
_count = int_in_range(5, 1000, "5 .. 1000")
_prior_error = float_in_range(0.0, 30.0, "0 .. 30 deg")


def _image_size(text: str) -> tuple[int, int]:
    """``WxH`` -> ``(height_px, width_px)``."""
    parts = text.lower().replace(" ", "").split("x")
    try:
        w, h = (int(v) for v in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels such as 1920x1080, "
                                         f"got {text!r}") from None
    if not (1 <= w <= 100000 and 1 <= h <= 100000):
        raise argparse.ArgumentTypeError(f"image size must be 1 .. 100000 px, got {text!r}")
    return h, w


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "solve", help="plate-solve an image: boresight RA/Dec, roll, FOV, WCS",
        description="Extract the stars of an image (FITS, PNG, TIFF, JPEG, .npy), identify "
                    "them against the Hipparcos catalog (lost-in-space) and fit the sensor "
                    "attitude in ICRS.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("inputs", nargs="*", metavar="IMAGE",
                   help="image file(s) (centroid files with --centroids)")
    cam = p.add_mutually_exclusive_group()
    cam.add_argument("--camera", metavar="NAME|FILE", help="camera preset (A1, A2, seed002, seed004) or TOML file")
    cam.add_argument("--fov-deg", type=_fov, help="horizontal field of view of a pinhole camera (deg; "
                                                  "default: searched blind)")
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
    p.add_argument("--centroids", action="store_true",
                   help="the inputs are centroid lists (x_px,y_px[,flux]); needs --image-size-px")
    p.add_argument("--image-size-px", type=_image_size, metavar="WxH",
                   help="image size of the centroid lists, e.g. 1920x1080")
    p.add_argument("--track", action="store_true",
                   help="solve the inputs as a sequence, each tracked from the previous attitude")
    p.add_argument("--prior-error-deg", type=_prior_error, default=None,
                   help="--track: bound on the attitude change between inputs (deg, default 1)")
    p.add_argument("--wcs-out", metavar="FILE", help="write a FITS copy of the image with its WCS")
    p.add_argument("--wcs-header", metavar="FILE",
                   help="write the WCS header alone, as text: 80-character cards, one a line")
    p.add_argument("--date-obs-is", choices=("start", "mid"), default="start",
                   help="what a FITS image's DATE-OBS means (default start, the FITS standard)")
    p.add_argument("--trust-flags", action="store_true",
                   help="use --camera even where the FITS header's SENSOR/INSTRUME names another sensor or camera "
                        "(recorded in the output; docs/file-formats.md, Header cross-checks)")
    p.add_argument("--json", action="store_true", help="print one JSON object (per input)")
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
    q = res.q_icrs_from_sensor_wxyz
    return (f"solved: RA {res.ra_deg:.4f} deg, Dec {res.dec_deg:+.4f} deg, roll {res.roll_deg:.3f} deg, "
            f"FOV {res.fov_deg:.4f} deg ({res.fov_search})\n"
            f"matched {res.matched} of {len(res.xy_px)} stars, rms {res.rms_arcsec:.1f} arcsec, "
            f"p_false {res.p_false:.1e}, {res.time_ms:.0f} ms\n"
            f"q_icrs_from_sensor_wxyz {q[0]:+.9f} {q[1]:+.9f} {q[2]:+.9f} {q[3]:+.9f}"
            + _time_line(res))


#: A centroid list's header names, and the column each one is (any order; case ignored)
_CENTROID_COLUMNS = {"x_px": 0, "x": 0, "y_px": 1, "y": 1, "flux": 2}


def _centroid_header(path, n: int, fields) -> list | None:
    """The columns' order ``[x, y(, flux)]`` a header line names, or None when it is not
    a header; ShipstarError when it names a column that is not one of those: read by
    position, ``y_px,x_px`` swapped the axes and ``x_px,y_px,mag`` ordered the stars
    faintest first, without a word."""
    from shipstar.errors import ShipstarError

    names = [f.strip().strip('"').lower() for f in fields]
    cols = [_CENTROID_COLUMNS.get(name) for name in names]
    if None in cols or sorted(cols) not in ([0, 1], [0, 1, 2]):
        raise ShipstarError(f"{path} line {n}: the header names {', '.join(names)}: expected x_px, y_px and "
                            f"optionally flux, in any order (or no header)")
    return [cols.index(want) for want in range(len(cols))]


def read_centroids(path):
    """``(xy_px (N, 2), flux (N,) or None)`` of a centroid list file (see the epilog):
    columns by the header's names when there is one, else ``x_px, y_px[, flux]``."""
    import numpy as np

    from shipstar.errors import ShipstarError

    rows, order = [], None
    with open(path, encoding="utf-8-sig", errors="replace") as fh:
        for n, line in enumerate(fh, 1):
            text = line.split("#", 1)[0].strip()
            if not text:
                continue
            fields = text.replace(",", " ").replace(";", " ").split()
            try:
                values = [float(v) for v in fields]
            except ValueError:
                if not rows and order is None and n <= 2:       # a header line (x_px,y_px,flux)
                    order = _centroid_header(path, n, fields)
                    continue
                raise ShipstarError(f"{path} line {n}: expected numbers x_px,y_px[,flux], "
                                    f"got {text[:40]!r}") from None
            if len(values) not in (2, 3) or (rows and len(values) != len(rows[0])) \
                    or (order is not None and len(values) != len(order)):
                raise ShipstarError(f"{path} line {n}: expected {len(order) if order else '2 or 3'} columns "
                                    f"(x_px,y_px[,flux]) on every line, got {len(values)}")
            if not all(np.isfinite(values)):
                raise ShipstarError(f"{path} line {n}: non-finite value")
            rows.append(values if order is None else [values[k] for k in order])
    if not rows:
        raise ShipstarError(f"{path}: no centroids (x_px,y_px[,flux] per line)")
    arr = np.asarray(rows, dtype=float)
    return arr[:, :2], (arr[:, 2] if arr.shape[1] == 3 else None)


def _check_inside(path, xy_px, size_px) -> None:
    """Refuse centroids outside the image (``size_px`` (height, width), as
    ``--image-size-px WxH`` gives it): pixel centres at 0 .. width - 1, so a star's
    centroid lies within -0.5 .. width - 0.5."""
    import numpy as np

    from shipstar.errors import ShipstarError

    h, w = size_px
    out = ~((xy_px[:, 0] >= -0.5) & (xy_px[:, 0] <= w - 0.5) & (xy_px[:, 1] >= -0.5) & (xy_px[:, 1] <= h - 0.5))
    if out.any():
        k = int(np.flatnonzero(out)[0])
        raise ShipstarError(f"{path}: {int(out.sum())} centroid(s) outside the {w}x{h} image given by "
                            f"--image-size-px, the first ({xy_px[k, 0]:g}, {xy_px[k, 1]:g}) px")


def _header_record(args, image) -> dict:
    """The header cross-checks of a FITS image against --camera (SENSOR/INSTRUME, image
    size): ShipstarError on a contradiction, the override record with --trust-flags.
    Imports only what a FITS image with --camera needs (``shipstar solve`` stays fast)."""
    if args.camera is None or args.centroids:
        return {}
    try:
        with open(Path(image), "rb") as fh:
            head = fh.read(9)
    except OSError:
        return {}                       # solve_image says why
    if head != b"SIMPLE  =" and not head.startswith(b"\x1f\x8b"):
        return {}                       # not FITS: no header to check
    from shipstar._fitsio import read_fits_header
    from shipstar.camera import load_camera
    from shipstar.cli._header_checks import header_check, override_record
    from shipstar.errors import ShipstarError

    try:
        info = read_fits_header(image, date_obs_is=args.date_obs_is)
    except ShipstarError:
        return {}                       # solve_image reads the pixels, or says why it cannot
    camera = load_camera(args.camera)
    check = header_check(args, names=(camera.name,), camera=camera, given_name=f"--camera {args.camera}")
    check(info)
    return override_record([check])


def _check_args(args) -> None:
    from shipstar.cli._common import check_output_file, check_outputs_apart
    from shipstar.errors import ShipstarError

    if not args.inputs:
        raise ShipstarError("give an image (or centroid files with --centroids)")
    if args.centroids and args.image_size_px is None:
        raise ShipstarError("--centroids needs --image-size-px WxH")
    if args.image_size_px is not None and not args.centroids:
        raise ShipstarError("--image-size-px is for --centroids (an image gives its own size)")
    if (args.wcs_out or args.wcs_header) and len(args.inputs) != 1:
        raise ShipstarError("--wcs-out / --wcs-header need exactly one input")
    if args.wcs_out and args.centroids:
        raise ShipstarError("--wcs-out copies an image: with --centroids use --wcs-header")
    if args.prior_error_deg is not None and not args.track:
        raise ShipstarError("--prior-error-deg bounds the attitude change between --track's inputs: give --track")
    if args.prior_error_deg is None:
        args.prior_error_deg = 1.0
    for flag, path in (("--wcs-out", args.wcs_out), ("--wcs-header", args.wcs_header)):
        if path:
            check_output_file(path, flag)
    check_outputs_apart(args, [("--wcs-out", args.wcs_out, None), ("--wcs-header", args.wcs_header, None)])


def _solve_one(args, item, prior):
    from shipstar.identify import solve_centroids, solve_image

    common = {"fov_tolerance": args.fov_tolerance, "mag_limit": args.mag_limit,
              "centroid_error_px": args.centroid_error_px, "max_stars": args.max_stars,
              "prior": prior, "prior_error_deg": args.prior_error_deg}
    camera = args.camera if prior is None else None
    fov = args.fov_deg if prior is None else None
    if args.centroids:
        xy, flux = read_centroids(item)
        _check_inside(item, xy, args.image_size_px)
        return solve_centroids(xy, args.image_size_px, camera=camera, fov_deg=fov, flux=flux, **common)
    return solve_image(item, camera=camera, fov_deg=fov, threshold_sigma=args.threshold_sigma,
                       date_obs_is=args.date_obs_is, **common)


def run(args) -> int:
    _check_args(args)
    many = len(args.inputs) > 1
    prior = None
    all_solved = True
    for item in args.inputs:
        record = _header_record(args, item)
        if record:
            from shipstar.cli._header_checks import print_overrides

            print_overrides("solve", record)
        res = _solve_one(args, item, prior)
        if args.track and res.solved:
            prior = res
        all_solved &= bool(res.solved)
        extra = {}
        if res.solved and (args.wcs_out or args.wcs_header):
            from shipstar.identify._wcs import write_wcs

            if args.wcs_out:
                write_wcs(res, args.wcs_out, image=item)
                extra["wcs_file"] = str(args.wcs_out)
            if args.wcs_header:
                write_wcs(res, args.wcs_header, image=None)
                extra["wcs_header_file"] = str(args.wcs_header)
        if args.json:
            emit_json({**({"input": str(item)} if many else {}), **res.as_json_dict(), **record,
                       **extra})
        else:
            text = _summary(res) + ("\n--trust-flags: the camera was used as given" if record else "")
            for key, path in extra.items():
                text += f"\n{'WCS image' if key == 'wcs_file' else 'WCS header'} written to {path}"
            print((f"{item}: " if many else "") + text)
    return 0 if all_solved else 1
