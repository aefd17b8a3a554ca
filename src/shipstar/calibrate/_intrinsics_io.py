"""Calibration frames from a directory: FITS images or JSON star lists.

**FITS images** (``*.fits``, ``*.fit``, ``*.fts``, each optionally ``.gz``: :func:`shipstar._fitsio.is_fits_name`, the one set every command reads; as ``shipstar simulate`` writes them):
the stars are extracted and identified (:func:`shipstar.identify.solve_image`, with a
focal length known to +-5 % and centroids to +-3 px, since the camera is not calibrated
yet).  They are read by :mod:`shipstar._fitsio` (the one FITS reader): the time is the
mid-exposure UTC (``DATE-AVG``, else ``DATE-BEG``/``DATE-OBS`` = start plus half of
``EXPTIME``; ``date_obs_is="mid"`` for cameras that write mid-exposure into
``DATE-OBS``), rows per ``ROWORDER``.  Other keywords used: ``INSTRUME`` or ``SENSOR``
(camera name), and for frames taken on the ground ``SITELAT``, ``SITELONG``,
``SITEELEV`` (deg, deg, m), ``PRESSURE`` (hPa), ``TEMPERAT`` (C), ``REFRMOD``.
``SIMFRAME = 'icrs'`` marks a simulated frame in space, rendered without aberration:
its reference directions are catalog places.

**JSON star lists** (``*.json``, not ``*.truth.json``), e.g. ``shipstar solve --json``
output (which gives ``stars``, ``date_obs``, ``camera``, ``width_px``, ``height_px``)::

    {"stars": [{"x_px": 812.4, "y_px": 97.1, "hip": 32349}, ...],
     "date_obs": "2024-03-15T20:16:00.000",         # or "utc"; else --date-obs
     "camera": "seed002", "width_px": 2560, "height_px": 1920,          # optional
     "lat_deg": 31.9, "lon_deg": 120.3, "height_m": 5.0,                # optional (ground)
     "pressure_hpa": 1021.7, "temperature_c": 11.1, "refraction_model": "almanac"}

A star's pixel position is ``x_px``, ``y_px``; ``x``, ``y`` (what ``shipstar solve``
wrote before) are accepted too.  Stars with ``hip`` missing, null or negative are
ignored; a list with ``"solved": false`` is skipped; a null or empty ``date_obs`` or
``camera`` counts as not given.  A directory holding FITS files is read as images (JSON files beside them
are ignored).  Values given to :func:`load_calibration_frames` (the command's flags)
override the files'.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shipstar._fitsio import DATE_OBS_CHOICES, FITS_SUFFIXES, NO_DATE_TEXT, is_fits_name
from shipstar.errors import ShipstarError

__all__ = ["LoadedFrames", "load_calibration_frames", "FITS_SUFFIXES",
           "IDENTIFY_FOV_TOLERANCE", "IDENTIFY_CENTROID_ERROR_PX"]

#: identification of images taken with a not yet calibrated camera
IDENTIFY_FOV_TOLERANCE = 0.05
IDENTIFY_CENTROID_ERROR_PX = 3.0
_TIME_KEYS = ("date_obs", "utc", "utc_mid_exposure", "DATE-OBS")
#: a star's pixel position: ``shipstar solve --json``'s keys, then the older ones
_XY_KEYS = (("x_px", "y_px"), ("x", "y"))


@dataclass(frozen=True)
class LoadedFrames:
    """Frames read from a directory.

    Attributes
    ----------
    frames : list of CalibrationFrame
    skipped : list of (str, str)
        ``(file name, reason)`` of files that gave no frame (not identified, unsolved).
    kind : str
        ``"fits"`` or ``"json"``.
    """

    frames: list
    skipped: list
    kind: str


@dataclass
class _Meta:
    """What a file says about its frame (None: not said)."""

    label: str
    utc: object = None
    camera_name: str | None = None
    image_shape_hw: tuple | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None
    height_m: float = 0.0
    pressure_hpa: float | None = None
    temperature_c: float | None = None
    relative_humidity: float | None = None
    refraction_model: str | None = None
    places: str = "apparent"
    time_problem: str = ""


def _number(value, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ShipstarError(f"{what} must be a finite number, got {value!r}")
    return float(value)


def _json_meta(path: Path, data: dict) -> _Meta:
    where = f"star list {path.name!r}"
    meta = _Meta(path.name)
    for key in _TIME_KEYS:
        if data.get(key) not in (None, ""):
            meta.utc = data[key]
            break
    cam = data.get("camera")
    if isinstance(cam, dict):
        cam = cam.get("name")
    if not isinstance(cam, str) or not cam:
        cam = data.get("camera_name")
    meta.camera_name = cam if isinstance(cam, str) and cam else None
    if data.get("width_px") is not None and data.get("height_px") is not None:
        meta.image_shape_hw = (int(_number(data["height_px"], f"{where}: height_px")),
                               int(_number(data["width_px"], f"{where}: width_px")))
    for key in ("lat_deg", "lon_deg", "height_m", "pressure_hpa", "temperature_c",
                "relative_humidity"):
        if data.get(key) is not None:
            setattr(meta, key, _number(data[key], f"{where}: {key}"))
    if data.get("refraction_model") is not None:
        meta.refraction_model = str(data["refraction_model"])
    if data.get("places") is not None:
        meta.places = str(data["places"])
    return meta


def _json_stars(path: Path):
    """``(xy (N, 2), hip (N,), meta)`` of a JSON star list, or a skip reason (str)."""
    where = f"star list {path.name!r}"
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise ShipstarError(f"cannot read {where}: {exc}") from None
    except json.JSONDecodeError as exc:
        raise ShipstarError(f"{where} is not valid JSON: {exc.msg} (line {exc.lineno})") from None
    if not isinstance(data, dict) or not isinstance(data.get("stars"), list):
        raise ShipstarError(f"{where} has no \"stars\" list of {{\"x_px\", \"y_px\", \"hip\"}} objects")
    if data.get("solved") is False:
        return f"not solved: {data.get('reason') or 'no reason given'}"
    xy, hip = [], []
    for k, star in enumerate(data["stars"]):
        keys = _XY_KEYS[0] if isinstance(star, dict) and _XY_KEYS[0][0] in star else _XY_KEYS[1]
        if not isinstance(star, dict) or keys[0] not in star or keys[1] not in star:
            raise ShipstarError(f"{where}: star {k} is not an object with \"x_px\" and \"y_px\" "
                                "(or \"x\" and \"y\")")
        h = star.get("hip")
        if h is None or isinstance(h, bool) or not isinstance(h, int) or h < 0:
            continue
        xy.append(tuple(_number(star[key], f"{where}: star {k} {key}") for key in keys))
        hip.append(h)
    return np.array(xy, float).reshape(-1, 2), np.array(hip, np.int64), _json_meta(path, data)


def _fits_meta(info) -> _Meta:
    """A :class:`shipstar._fitsio.FitsFrameInfo` as calibration metadata."""
    from shipstar.sky.time import iso_from_utc_jd

    meta = _Meta(info.name, image_shape_hw=tuple(info.shape_hw), time_problem=info.time_problem)
    if info.has_time:
        meta.utc = iso_from_utc_jd(info.utc_jd1, info.utc_jd2, 6).rstrip("Z")
    meta.camera_name = (info.instrume or info.sensor) or None
    for attr in ("lat_deg", "lon_deg", "height_m", "pressure_hpa", "temperature_c"):
        if getattr(info, attr) is not None:
            setattr(meta, attr, getattr(info, attr))
    meta.refraction_model = info.refraction_model or None
    if info.sim_frame == "icrs":
        meta.places = "catalog"
    return meta


def _fits_stars(path: Path, camera, database, date_obs_is: str = "start"):
    from shipstar._fitsio import read_fits
    from shipstar.identify import solve_image

    pixels, info = read_fits(path, date_obs_is=date_obs_is)
    meta = _fits_meta(info)
    if (pixels.shape[1], pixels.shape[0]) != (camera.width_px, camera.height_px):
        raise ShipstarError(f"frame {path.name!r} is {pixels.shape[1]}x{pixels.shape[0]} px but camera "
                            f"{camera.name!r} is {camera.width_px}x{camera.height_px} px")
    res = solve_image(pixels, camera=camera, fov_tolerance=IDENTIFY_FOV_TOLERANCE,
                      centroid_error_px=IDENTIFY_CENTROID_ERROR_PX, database=database)
    if not res.solved:
        return f"not identified: {res.reason}"
    keep = np.asarray(res.hip) >= 0
    return np.asarray(res.xy_px, float)[keep], np.asarray(res.hip, np.int64)[keep], meta


def _check_meta_ranges(meta: _Meta) -> None:
    """The site and weather a frame's header (or star list) gives, within the physical
    ranges of every entry point (:mod:`shipstar.limits`): ``PRESSURE = 0`` is refused."""
    from shipstar.limits import check_range

    for attr, key in (("lat_deg", "SITELAT"), ("lon_deg", "SITELONG"), ("pressure_hpa", "PRESSURE"),
                      ("temperature_c", "TEMPERAT"), ("relative_humidity", "relative_humidity")):
        value = getattr(meta, attr, None)
        if value is not None:
            check_range(attr, value, label=f"{key} ({attr})", where=f"frame {meta.label!r}")


def _frame_from(xy, hip, meta: _Meta, overrides: dict, catalog):
    from shipstar.calibrate.intrinsics import calibration_frame
    from shipstar.sky.apparent import Site
    from shipstar.sky.refraction import Weather
    from shipstar.sky.time import utc_jd_from_iso

    utc = meta.utc or overrides.get("utc")
    if meta.utc and overrides.get("utc"):                  # the flag is for frames that carry no time
        raise ShipstarError(f"frame {meta.label!r} carries its own time ({meta.utc}): --date-obs is for frames "
                            "that carry none")
    if utc is None and meta.time_problem and NO_DATE_TEXT not in meta.time_problem:
        raise ShipstarError(f"{meta.time_problem}; or give the time with --date-obs")
    if utc is None:
        raise ShipstarError(f"frame {meta.label!r} has no observation time (DATE-OBS / \"date_obs\"); "
                            "give it with --date-obs")
    jd = utc_jd_from_iso(str(utc).strip())
    _check_meta_ranges(meta)
    site = overrides.get("site")
    if site is None and meta.lat_deg is not None and meta.lon_deg is not None:
        site = Site.from_deg(meta.lat_deg, meta.lon_deg, meta.height_m)
    weather = overrides.get("weather")
    if weather is None and site is not None and meta.pressure_hpa is not None:
        weather = Weather(pressure_hpa=meta.pressure_hpa,
                          temperature_c=10.0 if meta.temperature_c is None else meta.temperature_c,
                          relative_humidity=meta.relative_humidity or 0.0)
    model = overrides.get("refraction_model") or meta.refraction_model or "erfa"
    places = "apparent" if site is not None else meta.places
    return calibration_frame(xy, hip, jd, catalog=catalog, site=site, weather=weather,
                             refraction_model=model, places=places, label=meta.label,
                             camera_name=meta.camera_name, image_shape_hw=meta.image_shape_hw)


def load_calibration_frames(directory, camera, *, utc: str | None = None, site=None,
                            weather=None, refraction_model: str | None = None,
                            catalog=None, date_obs_is: str = "start", progress=None) -> LoadedFrames:
    """Read every frame of ``directory`` (FITS images, else JSON star lists).

    Parameters
    ----------
    directory : path
    camera : Camera
        Nominal camera (identifies the images; image size checked).
    utc : str, optional
        Observation time (ISO 8601 UTC) for files that do not give one.
    site, weather, refraction_model : optional
        Override what the files say (a site puts every frame on the ground: apparent
        topocentric places and refraction).
    catalog : StarCatalog, optional
        Default: the full Hipparcos catalog.
    date_obs_is : {"start", "mid"}
        What the FITS files' DATE-OBS means when they have no DATE-AVG / DATE-BEG (the
        FITS standard: the start of the exposure).
    progress : callable(what, done, total), optional
        Called after each file (:class:`shipstar.pipeline._progress.ProgressBar`).

    A FITS file that cannot be read (truncated, not FITS, another image size) is skipped
    and listed with its reason, as every other command does with a frame that fails.

    Raises
    ------
    ShipstarError
        Not a directory, no frames in it, unreadable or malformed files, a frame without
        a time.
    """
    if date_obs_is not in DATE_OBS_CHOICES:
        raise ShipstarError(f"date_obs_is must be one of {', '.join(DATE_OBS_CHOICES)}, got {date_obs_is!r}")
    root = Path(directory)
    if not root.is_dir():
        raise ShipstarError(f"frames directory {str(root)!r} does not exist or is not a directory")
    files = sorted(p for p in root.iterdir() if p.is_file())
    fits_files = [p for p in files if is_fits_name(p.name)]
    json_files = [p for p in files if p.suffix.lower() == ".json"
                  and not p.name.lower().endswith(".truth.json")]
    if not fits_files and not json_files:
        raise ShipstarError(f"no frames in {str(root)!r}: expected FITS images (*.fits) or JSON "
                            "star lists (*.json)")
    if catalog is None:
        from shipstar.sky.catalog import load_hipparcos

        catalog = load_hipparcos()
    overrides = {"utc": utc, "site": site, "weather": weather, "refraction_model": refraction_model}
    database = None
    if fits_files:
        from shipstar.identify import build_database

        database = build_database(camera, fov_tolerance=IDENTIFY_FOV_TOLERANCE)
    frames, skipped = [], []
    todo = fits_files or json_files
    for k, path in enumerate(todo):
        if fits_files:
            try:
                got = _fits_stars(path, camera, database, date_obs_is)
            except (ShipstarError, OSError, ValueError) as exc:
                got = f"unreadable: {exc}"
        else:
            got = _json_stars(path)
        if progress is not None:
            progress("frames", k + 1, len(todo))
        if isinstance(got, str):
            skipped.append((path.name, got))
            continue
        frames.append(_frame_from(*got, overrides, catalog))
    return LoadedFrames(frames, skipped, "fits" if fits_files else "json")
