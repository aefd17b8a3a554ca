"""Installation TOML files (docs/file-formats.md): :func:`save_installation`, :func:`load_installation`."""

from __future__ import annotations

import json
import math
from pathlib import Path

from shipstar.errors import ShipstarError
from shipstar.units import ASEC2RAD, DEG2RAD, RAD2ASEC, RAD2DEG

__all__ = ["save_installation", "load_installation", "FORMAT_NAME", "FORMAT_VERSION"]

FORMAT_NAME = "shipstar-installation"
FORMAT_VERSION = 1

_AXES = ("az", "el", "roll")
_TOP_FLOATS = ("az_deg", "el_deg", "roll_deg") + tuple(f"std_{a}_arcsec" for a in _AXES) \
    + tuple(f"sem_{a}_arcsec" for a in _AXES) + tuple(f"total_{a}_arcsec" for a in _AXES)
_TOP_INTS = ("n_frames", "n_used", "n_failed", "n_rejected")
_TOP_STRS = ("format", "sensor", "camera", "session", "date_utc")
_DOCK_FLOATS = ("heading_deg", "pitch_deg", "roll_deg", "lat_deg", "lon_deg", "height_m", "pressure_hpa",
                "temperature_c", "xi_arcsec", "eta_arcsec", "dut1_error_s", "polar_motion_error_arcsec",
                "relative_humidity", "wavelength_um")
_DOCK_STRS = ("refraction_model", "refraction_mode", "eop_quality", "humidity_source", "eop_source")
#: Keys of each ``[[uncertainty]]`` row (the budget, docs/uncertainty.md).
_BUDGET_KEYS = ("source", "sigma", "az_arcsec", "el_arcsec", "roll_arcsec")
#: The physical range (shipstar.limits.RANGES) of each number read: a hand-edited
#: ``az_deg = 999`` is refused, not turned into an installation.
_LIMITS = {"az_deg": "install_az_deg", "el_deg": "install_el_deg", "roll_deg": "install_roll_deg",
           "dock.heading_deg": "heading_deg", "dock.pitch_deg": "pitch_deg", "dock.roll_deg": "roll_deg",
           "dock.lat_deg": "lat_deg", "dock.lon_deg": "lon_deg", "dock.pressure_hpa": "pressure_hpa",
           "dock.temperature_c": "temperature_c"}

_HEADER = """\
# shipstar installation calibration of one star sensor (docs/calibration-dock.md)
# C_deck_from_sensor = R_y(az) R_z(-el) R_x(-roll)   (seed 000 eq. 2, docs/conventions.md)
# az: boresight azimuth from the bow toward starboard; el: above the deck; roll: about the boresight.
# std_*: per-frame standard deviation over the session; sem_*: standard error of the mean.
"""


def _f(x) -> str:
    x = float(x)
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return repr(x)


def _s(text) -> str:
    return json.dumps(str(text), ensure_ascii=False)


def _render(inst) -> str:
    lines = [_HEADER.rstrip("\n"), f"format = {_s(FORMAT_NAME)}", f"format_version = {FORMAT_VERSION}",
             f"sensor = {_s(inst.sensor)}", f"camera = {_s(inst.camera)}", f"session = {_s(inst.session)}",
             f"date_utc = {_s(inst.date_utc)}", "",
             f"az_deg = {_f(inst.az_rad * RAD2DEG)}", f"el_deg = {_f(inst.el_rad * RAD2DEG)}",
             f"roll_deg = {_f(inst.roll_rad * RAD2DEG)}"]
    for prefix, values in (("std", inst.std_arcsec), ("sem", inst.sem_arcsec), ("total", inst.total_arcsec)):
        lines += [f"{prefix}_{a}_arcsec = {_f(v)}" for a, v in zip(_AXES, values)]
    lines += [f"{k} = {int(getattr(inst, k))}" for k in _TOP_INTS]
    lines.append(f"warnings = [{', '.join(_s(w) for w in inst.warnings)}]")
    if inst.trust_flags:        # --trust-flags: the header contradictions it overrode (docs/file-formats.md)
        lines += ["trust_flags = true", f"header_overrides = [{', '.join(_s(w) for w in inst.header_overrides)}]"]
    if getattr(inst, "at_sea", None):
        lines.append("at_sea = true            # re-estimated at sea relative to a reference sensor")
    d = inst.dock
    if d is not None:
        lines += ["", "[dock]", f"heading_deg = {_f(d.heading_rad * RAD2DEG)}",
                  f"pitch_deg = {_f(d.pitch_rad * RAD2DEG)}", f"roll_deg = {_f(d.roll_rad * RAD2DEG)}",
                  f"lat_deg = {_f(d.lat_rad * RAD2DEG)}", f"lon_deg = {_f(d.lon_rad * RAD2DEG)}",
                  f"height_m = {_f(d.height_m)}",
                  f"xi_arcsec = {_f(d.xi_rad * RAD2ASEC)}      # deflection of the vertical (levels follow it)",
                  f"eta_arcsec = {_f(d.eta_rad * RAD2ASEC)}",
                  f"pressure_hpa = {_f(d.pressure_hpa)}",
                  f"temperature_c = {_f(d.temperature_c)}", f"refraction_model = {_s(d.refraction_model)}",
                  f"refraction_mode = {_s(d.refraction_mode)}",
                  f"eop_quality = {_s(d.eop_quality)}          # Earth orientation: measured, predicted, extrapolated",
                  f"dut1_error_s = {_f(d.dut1_error_s)}",
                  f"polar_motion_error_arcsec = {_f(d.polar_motion_error_arcsec)}",
                  f"relative_humidity = {_f(d.relative_humidity)}",
                  f"humidity_source = {_s(d.humidity_source)}      # given, or default (0 = dry air assumed)",
                  f"wavelength_um = {_f(d.wavelength_um)}         # effective wavelength: the camera's wavelength_um",
                  f"eop_source = {_s(d.eop_source)}"]
    if getattr(inst, "at_sea", None):      # calibrate install --at-sea: where the angles come from
        lines += ["", "[at_sea_calibration]"]
        lines += [f"{k} = {_s(v) if isinstance(v, str) else _f(v) if isinstance(v, float) else int(v)}"
                  for k, v in inst.at_sea.items()]
    for row in inst.uncertainty:     # the budget of total_*_arcsec (docs/uncertainty.md)
        lines += ["", "[[uncertainty]]", f"source = {_s(row['source'])}", f"sigma = {_s(row['sigma'])}"]
        lines += [f"{a}_arcsec = {_f(row[a + '_arcsec'])}" for a in _AXES]
    return "\n".join(lines) + "\n"


def save_installation(inst, path) -> None:
    """Write an :class:`~shipstar.calibrate.installation.Installation` as TOML.

    Written to a temporary file in the same directory and renamed, so a crash never
    leaves a half-written file that looks complete.
    """
    from shipstar._atomic import atomic_write_text

    atomic_write_text(path, _render(inst))


def _read_toml(path: Path) -> dict:
    import tomllib

    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ShipstarError(f"no such installation file: {path}") from None
    except IsADirectoryError:
        raise ShipstarError(f"installation file {path} is a directory") from None
    except tomllib.TOMLDecodeError as exc:
        raise ShipstarError(f"installation file {path} is not valid TOML: {exc}") from None
    except UnicodeDecodeError:
        raise ShipstarError(f"installation file {path} is not UTF-8 text") from None


def _check_keys(table: dict, allowed: tuple, where: str, path: Path) -> None:
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        raise ShipstarError(f"installation file {path}: unknown key {where}{unknown[0]!r}")


def _number(table: dict, key: str, where: str, path: Path, *, required: bool, finite: bool) -> float:
    if key not in table:
        if required:
            raise ShipstarError(f"installation file {path}: missing {where}{key}")
        return math.nan
    value = table[key]
    if isinstance(value, str) and key.endswith("_deg"):          # degrees-minutes-seconds
        from shipstar.limits import parse_angle_deg

        try:
            value = parse_angle_deg(value)
        except ShipstarError:
            raise ShipstarError(f"installation file {path}: {where}{key} must be a number or degrees-minutes-"
                                f"seconds (\"46d28m28.51s\", \"46:28:28.51\"), got {value!r}") from None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ShipstarError(f"installation file {path}: {where}{key} must be a number, got {value!r}")
    if finite and not math.isfinite(value):
        raise ShipstarError(f"installation file {path}: {where}{key} must be finite, got {value!r}")
    limit = _LIMITS.get(where + key)
    if limit is not None and math.isfinite(value):
        from shipstar.limits import check_range

        check_range(limit, value, label=where + key, where=f"installation file {path}")
    return float(value)


def _text(table: dict, key: str, where: str, path: Path, *, required: bool) -> str:
    if key not in table:
        if required:
            raise ShipstarError(f"installation file {path}: missing {where}{key}")
        return ""
    value = table[key]
    if not isinstance(value, str):
        raise ShipstarError(f"installation file {path}: {where}{key} must be a string, got {value!r}")
    return value


def _dock(table, path: Path):
    from shipstar.calibrate._installation_model import DockConditions

    if not isinstance(table, dict):
        raise ShipstarError(f"installation file {path}: [dock] must be a table")
    _check_keys(table, _DOCK_FLOATS + _DOCK_STRS, "dock.", path)
    num = {k: _number(table, k, "dock.", path, required=k == "heading_deg",
                      finite=k in ("heading_deg", "xi_arcsec", "eta_arcsec")) for k in _DOCK_FLOATS}

    def zero_if_nan(x):                 # files written before a key existed: it was 0
        return 0.0 if math.isnan(x) else x

    quality = _text(table, "eop_quality", "dock.", path, required=False)
    if quality not in ("", "measured", "predicted", "extrapolated"):
        raise ShipstarError(f"installation file {path}: dock.eop_quality must be measured, predicted or "
                            f"extrapolated, got {quality!r}")
    return DockConditions(
        heading_rad=num["heading_deg"] * DEG2RAD,
        pitch_rad=zero_if_nan(num["pitch_deg"]) * DEG2RAD, roll_rad=zero_if_nan(num["roll_deg"]) * DEG2RAD,
        lat_rad=num["lat_deg"] * DEG2RAD, lon_rad=num["lon_deg"] * DEG2RAD, height_m=zero_if_nan(num["height_m"]),
        pressure_hpa=num["pressure_hpa"], temperature_c=num["temperature_c"],
        refraction_model=_text(table, "refraction_model", "dock.", path, required=False),
        refraction_mode=_text(table, "refraction_mode", "dock.", path, required=False),
        xi_rad=zero_if_nan(num["xi_arcsec"]) * ASEC2RAD, eta_rad=zero_if_nan(num["eta_arcsec"]) * ASEC2RAD,
        eop_quality=quality, dut1_error_s=num["dut1_error_s"],
        polar_motion_error_arcsec=num["polar_motion_error_arcsec"],
        relative_humidity=num["relative_humidity"], wavelength_um=num["wavelength_um"],
        humidity_source=_text(table, "humidity_source", "dock.", path, required=False),
        eop_source=_text(table, "eop_source", "dock.", path, required=False))


def _uncertainty(doc: dict, path: Path) -> tuple:
    rows = doc.get("uncertainty", [])
    if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
        raise ShipstarError(f"installation file {path}: uncertainty must be [[uncertainty]] tables")
    out = []
    for r in rows:
        _check_keys(r, _BUDGET_KEYS, "uncertainty.", path)
        out.append({"source": _text(r, "source", "uncertainty.", path, required=True),
                    "sigma": _text(r, "sigma", "uncertainty.", path, required=True),
                    **{f"{a}_arcsec": _number(r, f"{a}_arcsec", "uncertainty.", path, required=True, finite=True)
                       for a in _AXES}})
    return tuple(out)


def _warnings(doc: dict, path: Path) -> tuple:
    value = doc.get("warnings", [])
    if not isinstance(value, list) or not all(isinstance(w, str) for w in value):
        raise ShipstarError(f"installation file {path}: warnings must be a list of strings, got {value!r}")
    return tuple(value)


def _trust_flags(doc: dict, path: Path) -> dict:
    trust = doc.get("trust_flags", False)
    if not isinstance(trust, bool):
        raise ShipstarError(f"installation file {path}: trust_flags must be true or false, got {trust!r}")
    value = doc.get("header_overrides", [])
    if not isinstance(value, list) or not all(isinstance(w, str) for w in value):
        raise ShipstarError(f"installation file {path}: header_overrides must be a list of strings, got {value!r}")
    return {"trust_flags": trust, "header_overrides": tuple(value)}


def load_installation(path):
    """Read an installation TOML file.

    Raises
    ------
    ShipstarError
        Missing file, bad TOML, wrong format name or version, a missing or mistyped field
        (named in the message), an unknown key.
    """
    from shipstar.calibrate._installation_model import Installation

    path = Path(path)
    doc = _read_toml(path)
    _check_keys(doc, _TOP_FLOATS + _TOP_INTS + _TOP_STRS + ("format_version", "dock", "warnings", "trust_flags",
                                                            "header_overrides", "uncertainty", "at_sea",
                                                            "at_sea_calibration"), "", path)
    if doc.get("format", FORMAT_NAME) != FORMAT_NAME:
        raise ShipstarError(f"installation file {path}: format is {doc.get('format')!r}, expected {FORMAT_NAME!r}")
    version = doc.get("format_version", FORMAT_VERSION)
    if version != FORMAT_VERSION:
        raise ShipstarError(f"installation file {path}: format_version {version!r} is not supported "
                            f"(this shipstar reads {FORMAT_VERSION})")
    angles = [_number(doc, f"{a}_deg", "", path, required=True, finite=True) * DEG2RAD for a in _AXES]
    counts = {}
    for k in _TOP_INTS:
        v = doc.get(k, 0)
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise ShipstarError(f"installation file {path}: {k} must be a non-negative integer, got {v!r}")
        counts[k] = v
    std = tuple(_number(doc, f"std_{a}_arcsec", "", path, required=False, finite=False) for a in _AXES)
    sem = tuple(_number(doc, f"sem_{a}_arcsec", "", path, required=False, finite=False) for a in _AXES)
    total = tuple(_number(doc, f"total_{a}_arcsec", "", path, required=False, finite=False) for a in _AXES)
    date_utc = _text(doc, "date_utc", "", path, required=False)
    if date_utc:                                        # the calibration's date: an ISO UTC time
        from shipstar.sky.time import utc_jd_from_iso

        try:
            utc_jd_from_iso(date_utc)
        except ShipstarError as exc:
            raise ShipstarError(f"installation file {path}: date_utc: {exc}") from None
    return Installation(
        sensor=_text(doc, "sensor", "", path, required=True), camera=_text(doc, "camera", "", path, required=True),
        az_rad=angles[0], el_rad=angles[1], roll_rad=angles[2], std_arcsec=std, sem_arcsec=sem,
        session=_text(doc, "session", "", path, required=False), date_utc=date_utc,
        dock=_dock(doc["dock"], path) if "dock" in doc else None, warnings=_warnings(doc, path), **counts,
        **_trust_flags(doc, path), total_arcsec=total, uncertainty=_uncertainty(doc, path),
        at_sea=_at_sea(doc, path))


#: ``[at_sea_calibration]`` keys (``calibrate install --at-sea``) and their types.
AT_SEA_KEYS = {"reference_sensor": str, "start_utc": str, "end_utc": str, "n_epochs": int,
               "rot_bow_arcsec": float, "rot_up_arcsec": float, "rot_starboard_arcsec": float,
               "sigma_bow_arcsec": float, "sigma_up_arcsec": float, "sigma_starboard_arcsec": float,
               "clock_offset_s": float, "clock_sigma_s": float, "previous_installation": str}


def _at_sea(doc: dict, path: Path):
    flag = doc.get("at_sea", False)
    if not isinstance(flag, bool):
        raise ShipstarError(f"installation file {path}: at_sea must be true or false, got {flag!r}")
    table = doc.get("at_sea_calibration")
    if not flag:
        if table is not None:
            raise ShipstarError(f"installation file {path}: [at_sea_calibration] needs at_sea = true")
        return None
    if not isinstance(table, dict):
        raise ShipstarError(f"installation file {path}: at_sea = true needs an [at_sea_calibration] table")
    _check_keys(table, tuple(AT_SEA_KEYS), "at_sea_calibration.", path)
    out = {}
    for k, v in table.items():
        want = AT_SEA_KEYS[k]
        ok = isinstance(v, str) if want is str else (isinstance(v, int) and not isinstance(v, bool)) if want is int \
            else isinstance(v, (int, float)) and not isinstance(v, bool)
        if not ok:
            raise ShipstarError(f"installation file {path}: at_sea_calibration.{k} must be {want.__name__}, got {v!r}")
        out[k] = float(v) if want is float else v
    return out
