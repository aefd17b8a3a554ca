"""Writing simulated frames: a FITS image (one HDU, uint16) and a truth JSON file beside it.

``write_frame(frame, "x.fits")`` writes ``x.fits`` and ``x.truth.json``.  Each file is
written to a temporary file in the same directory and renamed into place, so a crash
never leaves a half-written file under the final name; an older truth file of the same
name is removed before the new FITS file appears, and the truth file records the
SHA-256 of the image it describes (:func:`read_truth` checks it), so a FITS file and a
truth file that do not belong together are detected.  The schema is in
``docs/simulation.md``.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from shipstar.errors import ShipstarError
from shipstar.frames import (
    q_wxyz_from_matrix,
    ra_dec_from_unit,
    ra_dec_roll_from_C_icrs_from_sensor,
    ship_angles_from_C_hor_from_deck,
)
from shipstar.units import RAD2ASEC, RAD2DEG

__all__ = ["TRUTH_SCHEMA", "write_frame", "truth_dict", "truth_path_for", "read_truth", "image_sha256",
           "fits_header_cards"]

#: Identifies the truth file format; bumped on any incompatible change.
TRUTH_SCHEMA = "shipstar.simulate.truth/1"
_FITS_SUFFIXES = (".fits", ".fit", ".fts")


def truth_path_for(fits_path) -> Path:
    """``frame.fits`` -> ``frame.truth.json`` (any other name: ``name + ".truth.json"``)."""
    path = Path(fits_path)
    if path.suffix.lower() in _FITS_SUFFIXES:
        path = path.with_suffix("")
    return path.with_name(path.name + ".truth.json")


def image_sha256(image) -> str:
    """SHA-256 (hex) of an image's pixels as little-endian uint16, row-major."""
    arr = np.ascontiguousarray(np.asarray(image).astype("<u2", casting="unsafe"))
    return hashlib.sha256(arr.tobytes()).hexdigest()


def _matrix(C) -> list:
    return np.asarray(C, float).tolist()


def _attitude_icrs(C) -> dict:
    ra, dec, roll = ra_dec_roll_from_C_icrs_from_sensor(C)
    return {"C_icrs_from_sensor": _matrix(C), "q_wxyz_icrs_from_sensor": q_wxyz_from_matrix(C).tolist(),
            "ra_deg": float(ra) * RAD2DEG, "dec_deg": float(dec) * RAD2DEG, "roll_deg": float(roll) * RAD2DEG}


def _attitude_hor(frame) -> dict:
    C = frame.C_hor_from_sensor
    az, el, roll = ship_angles_from_C_hor_from_deck(C)
    site, w, eop = frame.context.site, frame.weather, frame.context.eop
    out = {
        "C_hor_from_sensor": _matrix(C), "q_wxyz_hor_from_sensor": q_wxyz_from_matrix(C).tolist(),
        "sensor_az_deg": float(az) * RAD2DEG, "sensor_el_deg": float(el) * RAD2DEG,
        "sensor_roll_deg": float(roll) * RAD2DEG,
        "site": {"lat_deg": site.lat_rad * RAD2DEG, "lon_deg": site.lon_rad * RAD2DEG, "height_m": site.height_m,
                 "xi_arcsec": site.xi_rad * RAD2ASEC, "eta_arcsec": site.eta_rad * RAD2ASEC},
        "weather": {"pressure_hpa": w.pressure_hpa, "temperature_c": w.temperature_c,
                    "relative_humidity": w.relative_humidity, "wavelength_um": w.wavelength_um},
        "refraction_model": frame.refraction_model,
        "eop": {"dut1_s": eop.dut1_s, "xp_arcsec": eop.xp_rad * RAD2ASEC, "yp_arcsec": eop.yp_rad * RAD2ASEC,
                "quality": eop.quality},
    }
    if frame.ship is not None:
        s = frame.ship
        out.update({
            "heading_deg": s.heading_rad * RAD2DEG, "pitch_deg": s.pitch_rad * RAD2DEG,
            "ship_roll_deg": s.roll_rad * RAD2DEG, "install_az_deg": s.install_az_rad * RAD2DEG,
            "install_el_deg": s.install_el_rad * RAD2DEG, "install_roll_deg": s.install_roll_rad * RAD2DEG,
            "C_hor_from_deck": _matrix(s.C_hor_from_deck), "C_deck_from_sensor": _matrix(s.C_deck_from_sensor),
        })
    return out


def _stars(stars) -> dict:
    out = {"hip": stars.hip.tolist(), "xy_px": stars.xy_px.tolist(), "mag": stars.mag.tolist(),
           "signal_e": stars.signal_e.tolist(), "smear_px": stars.smear_px.tolist(),
           "u_sensor": stars.u_sensor.tolist(), "ref_frame": stars.ref_frame, "v_ref": stars.v_ref.tolist()}
    if stars.ref_frame == "hor":
        el = np.arctan2(stars.v_ref[:, 1], np.hypot(stars.v_ref[:, 0], stars.v_ref[:, 2]))
        az = np.mod(np.arctan2(stars.v_ref[:, 2], stars.v_ref[:, 0]), 2 * np.pi)
        out.update(az_deg=(az * RAD2DEG).tolist(), el_deg=(el * RAD2DEG).tolist(),
                   refraction_arcsec=(stars.refraction_rad * RAD2ASEC).tolist())
    else:
        ra, dec = ra_dec_from_unit(stars.v_ref)
        out.update(ra_deg=(ra * RAD2DEG).tolist(), dec_deg=(dec * RAD2DEG).tolist())
    return out


def _false_objects(fo) -> dict:
    return {"planet_xy_px": fo.planet_xy_px.tolist(), "planet_signal_e": fo.planet_signal_e.tolist(),
            "trail_xy_px": fo.trail_xy_px.tolist(), "trail_signal_e": fo.trail_signal_e.tolist(),
            "cosmic_ray_count": int(fo.cosmic_ray_count), "cosmic_ray_e": float(fo.cosmic_ray_e)}


def truth_dict(frame, fits_name: str | None = None) -> dict:
    """The truth of a :class:`SimulatedFrame` as a JSON-ready dict (schema: ``docs/simulation.md``)."""
    out = {
        "schema": TRUTH_SCHEMA,
        "fits_file": fits_name,
        "image_sha256": image_sha256(frame.image),
        "image_shape_hw_px": list(frame.image.shape),
        "camera_name": frame.camera_name,
        "camera": frame.camera.as_dict(),
        "utc_mid_exposure": _iso6(frame.utc_jd1, frame.utc_jd2) + "Z",
        "exposure_s": frame.exposure_s,
        "epoch_jyear": frame.epoch_jyear,
        "seed": frame.seed,
        "mag_limit": frame.mag_limit,
        "hot_pixel_fraction": frame.hot_pixel_fraction,
        "frame": frame.frame,
        "omega_sensor_rad_per_s": np.asarray(frame.omega_sensor_rad_per_s, float).tolist(),
        "n_stars": len(frame.stars),
    }
    out.update(_attitude_icrs(frame.C_icrs_from_sensor))
    if frame.frame == "hor":
        out.update(_attitude_hor(frame))
    out["stars"] = _stars(frame.stars)
    out["false_objects"] = _false_objects(frame.false_objects)
    return out


def _wcs_cards(frame) -> list:
    """TAN WCS of a "space" frame of an undistorted camera (exact there); else none."""
    cam = frame.camera
    if frame.frame != "icrs" or not cam.distortion.is_zero:
        return []
    C = np.asarray(frame.C_icrs_from_sensor, float)
    ra, dec, _ = ra_dec_roll_from_C_icrs_from_sensor(C)
    east = np.array([-np.sin(ra), np.cos(ra), 0.0])
    north = np.array([-np.sin(dec) * np.cos(ra), -np.sin(dec) * np.sin(ra), np.cos(dec)])
    s = cam.pixel_mm / cam.f_mm * RAD2DEG
    cd = [[C[:, 2] @ east * s, -(C[:, 1] @ east) * s], [C[:, 2] @ north * s, -(C[:, 1] @ north) * s]]
    return [("WCSAXES", 2, "pinhole TAN projection, exact for this frame"),
            ("CTYPE1", "RA---TAN", ""), ("CTYPE2", "DEC--TAN", ""),
            ("CUNIT1", "deg", ""), ("CUNIT2", "deg", ""), ("RADESYS", "ICRS", ""),
            ("CRPIX1", cam.x0_px + 1.0, "principal point x + 1 (FITS pixels are 1-based)"),
            ("CRPIX2", cam.y0_px + 1.0, "principal point y + 1"),
            ("CRVAL1", float(ra) * RAD2DEG, "[deg] boresight RA"), ("CRVAL2", float(dec) * RAD2DEG, "[deg] boresight Dec"),
            ("CD1_1", cd[0][0], ""), ("CD1_2", cd[0][1], ""), ("CD2_1", cd[1][0], ""), ("CD2_2", cd[1][1], "")]


def _iso6(jd1: float, jd2: float) -> str:
    """ISO 8601 UTC with microseconds, without the ``Z`` (FITS date format)."""
    from shipstar.sky.time import iso_from_utc_jd

    return iso_from_utc_jd(jd1, jd2, 6).rstrip("Z")


def _time_cards(frame) -> list:
    """FITS 4.0 time cards: DATE-OBS = DATE-BEG = start, DATE-AVG = mid, DATE-END = end."""
    from shipstar.sky.time import mjd_from_jd

    half_d = 0.5 * frame.exposure_s / 86400.0
    jd = {"BEG": (frame.utc_jd1, frame.utc_jd2 - half_d), "AVG": (frame.utc_jd1, frame.utc_jd2),
          "END": (frame.utc_jd1, frame.utc_jd2 + half_d)}
    what = {"BEG": "start of exposure", "AVG": "mid-exposure", "END": "end of exposure"}
    cards = [("DATE-OBS", _iso6(*jd["BEG"]), "UTC, start of exposure (FITS standard)")]
    cards += [(f"DATE-{k}", _iso6(*v), f"UTC, {what[k]}") for k, v in jd.items()]
    cards += [("MJD-OBS", float(mjd_from_jd(*jd["BEG"])), "[d] UTC MJD, start of exposure")]
    cards += [(f"MJD-{k}", float(mjd_from_jd(*v)), f"[d] UTC MJD, {what[k]}") for k, v in jd.items()]
    return cards + [("TIMESYS", "UTC", ""), ("EXPTIME", frame.exposure_s, "[s] exposure time")]


def fits_header_cards(frame, sensor: str | None = None) -> list:
    """FITS header cards ``(keyword, value, comment)`` of a frame; ``INSTRUME`` names its
    camera and ``SENSOR`` the sensor (``sensor``, default the camera's name), as the
    header checks read them (:mod:`shipstar.pipeline._header_check`).

    Times with microseconds: ``DATE-OBS`` and ``DATE-BEG`` at the start of the exposure
    (FITS 4.0), ``DATE-AVG`` at mid-exposure (the truth time), ``DATE-END`` at its end;
    ``ROWORDER = 'TOP-DOWN'`` (row 0 of the data is the top of the image).
    """
    from shipstar import __version__

    cam = frame.camera
    q = q_wxyz_from_matrix(frame.C_icrs_from_sensor)
    cards = _time_cards(frame) + [
        ("ROWORDER", "TOP-DOWN", "first row stored is the top of the image"),
        ("INSTRUME", cam.name, "camera model"), ("SENSOR", cam.name if sensor is None else sensor, "star sensor"),
        ("ORIGIN", f"shipstar {__version__}", "simulated frame"),
        ("BUNIT", "adu", ""), ("FOCALLEN", cam.f_mm, "[mm] focal length"),
        ("XPIXSZ", cam.pixel_mm * 1000.0, "[um] pixel size"), ("YPIXSZ", cam.pixel_mm * 1000.0, "[um] pixel size"),
        ("GAIN", cam.gain_e_per_adu, "[e/adu]"), ("RDNOISE", cam.read_noise_e, "[e] read noise"),
        ("SATURATE", cam.adc_max_adu, "[adu] ADC maximum"),
        ("SIMSEED", frame.seed, "noise seed"), ("SIMFRAME", frame.frame, "geometry: icrs (space) or hor (Earth)"),
        ("NSTARS", len(frame.stars), "catalog stars in the frame (truth file)"),
        ("QICRS_W", float(q[0]), "q_wxyz_icrs_from_sensor"), ("QICRS_X", float(q[1]), ""),
        ("QICRS_Y", float(q[2]), ""), ("QICRS_Z", float(q[3]), ""),
    ]
    if frame.mag_limit is not None:
        cards.append(("MAGLIMIT", frame.mag_limit, "faintest Hp magnitude simulated"))
    if frame.frame == "hor":
        site, w = frame.context.site, frame.weather
        cards += [("SITELAT", site.lat_rad * RAD2DEG, "[deg] geodetic latitude"),
                  ("SITELONG", site.lon_rad * RAD2DEG, "[deg] longitude, east positive"),
                  ("SITEELEV", site.height_m, "[m] height above WGS84"),
                  ("PRESSURE", w.pressure_hpa, "[hPa]"), ("TEMPERAT", w.temperature_c, "[C] air temperature"),
                  ("REFRMOD", frame.refraction_model, "refraction model")]
    return cards + _wcs_cards(frame)


def _atomic_replace(path: Path, write) -> None:
    """``write(tmp_path)`` into a temporary file beside ``path``, then rename it over ``path``."""
    from shipstar._atomic import atomic_path

    with atomic_path(path) as tmp:
        write(tmp)


def write_frame(frame, path, sensor: str | None = None) -> tuple[Path, Path]:
    """Write ``frame`` as a FITS file and its truth JSON beside it.

    Parameters
    ----------
    frame : SimulatedFrame
    path : str or Path
        The FITS file, e.g. ``frame.fits``; the truth goes to :func:`truth_path_for`.
    sensor : str, optional
        The sensor's name for the ``SENSOR`` card (default the camera's name).

    Returns
    -------
    (fits_path, truth_path)
    """
    from astropy.io import fits

    from shipstar.simulate._frame import SimulatedFrame

    if not isinstance(frame, SimulatedFrame):
        raise ShipstarError(f"write_frame needs a SimulatedFrame, got {type(frame).__name__}")
    fits_path, truth_path = Path(path), truth_path_for(path)
    if fits_path.is_dir():
        raise ShipstarError(f"{fits_path} is a directory, not a FITS file name")
    hdu = fits.PrimaryHDU(np.asarray(frame.image, dtype=np.uint16))
    for key, value, comment in fits_header_cards(frame, sensor):
        hdu.header[key] = (value, comment)
    text = json.dumps(truth_dict(frame, fits_path.name), allow_nan=False, indent=1) + "\n"
    truth_path.unlink(missing_ok=True)                  # never leave an old truth beside a new image
    _atomic_replace(fits_path, lambda tmp: hdu.writeto(tmp, overwrite=True, checksum=True))
    _atomic_replace(truth_path, lambda tmp: tmp.write_text(text, encoding="utf-8"))
    return fits_path, truth_path


def _read_fits_image(path: Path) -> np.ndarray:
    from shipstar._fitsio import read_fits_image

    if not path.exists():
        raise ShipstarError(f"no FITS file {path} beside its truth file")
    return read_fits_image(path)


def read_truth(path, *, check_image: bool = True) -> dict:
    """Read a truth JSON file (and, by default, check it belongs to the FITS file beside it).

    Parameters
    ----------
    path : str or Path
        The truth file (``*.truth.json``) or its FITS file.
    check_image : bool
        Compare the image SHA-256 with the FITS file named in the truth.

    Raises
    ------
    ShipstarError
        Missing or unreadable file, another schema, or an image that does not match.
    """
    path = Path(path)
    if path.suffix.lower() in _FITS_SUFFIXES:
        path = truth_path_for(path)
    try:
        truth = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ShipstarError(f"no truth file {path}") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ShipstarError(f"cannot read truth file {path}: {exc}") from None
    if not isinstance(truth, dict) or truth.get("schema") != TRUTH_SCHEMA:
        raise ShipstarError(f"{path} is not a shipstar truth file ({TRUTH_SCHEMA})")
    if check_image and truth.get("fits_file"):
        if image_sha256(_read_fits_image(path.with_name(truth["fits_file"]))) != truth.get("image_sha256"):
            raise ShipstarError(f"truth file {path} does not describe the image in {truth['fits_file']}")
    return truth
