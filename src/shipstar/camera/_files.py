"""Camera files (TOML) and the packaged presets.

A camera file holds every :class:`~shipstar.camera.Camera` field at the top level and the
distortion coefficients in an optional ``[distortion]`` table (absent keys are zero).
Unknown keys are errors, so a typo never silently drops a parameter.
"""

from __future__ import annotations

import functools
import json
import math
import os
import tomllib
from dataclasses import fields
from pathlib import Path

from shipstar.camera._distortion import Distortion
from shipstar.camera._model import Camera, _FieldError
from shipstar.errors import ShipstarError

__all__ = ["PRESETS", "camera_preset", "load_camera", "save_camera", "camera_from_toml_text",
           "camera_to_toml_text"]

#: Names of the packaged camera presets (src/shipstar/data/cameras/<name>.toml).
PRESETS = ("A1", "A2", "seed002", "seed004")

_CAMERA_KEYS = tuple(f.name for f in fields(Camera) if f.name != "distortion")
_DISTORTION_KEYS = tuple(f.name for f in fields(Distortion))
_OPTIONAL_KEYS = frozenset({"notes", "wavelength_um", "wavelength_sigma_um"})   # default when absent


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def camera_from_toml_text(text: str, source: str) -> Camera:
    """Parse a camera file's text; ``source`` names it in error messages."""
    where = f"camera file {source!r}"
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ShipstarError(f"{where}: not valid TOML: {_one_line(exc)}") from None
    unknown = sorted(set(data) - set(_CAMERA_KEYS) - {"distortion"})
    if unknown:
        raise ShipstarError(f"{where}: unknown field {unknown[0]!r}")
    missing = [k for k in _CAMERA_KEYS if k not in data and k not in _OPTIONAL_KEYS]
    if missing:
        raise ShipstarError(f"{where}: missing field {missing[0]!r}")
    dist = data.get("distortion", {})
    if not isinstance(dist, dict):
        raise ShipstarError(f"{where}: field 'distortion' must be a table [distortion]")
    unknown = sorted(set(dist) - set(_DISTORTION_KEYS))
    if unknown:
        raise ShipstarError(f"{where}: unknown field 'distortion.{unknown[0]}'")
    for key, value in dist.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ShipstarError(f"{where}: field 'distortion.{key}' must be a finite number, got {value!r}")
    kwargs = {k: data[k] for k in _CAMERA_KEYS if k in data}
    for key, value in kwargs.items():
        # TOML floats for integer fields are a type error, not something to round
        if isinstance(value, float) and key in ("width_px", "height_px", "adc_bits"):
            raise ShipstarError(f"{where}: field {key!r} must be an integer, got {value!r}")
    try:
        camera = Camera(distortion=Distortion(**dist), **kwargs)
    except _FieldError as exc:
        raise ShipstarError(f"{where}: field {exc.field!r} {exc.problem}") from None
    except ShipstarError as exc:
        raise ShipstarError(f"{where}: {exc}") from None
    # a star sensor's principal point lies on its sensor: a typo such as 5000 for 500 would
    # turn every direction by degrees (checked in files, not in the Camera itself, whose
    # intermediate fits may step outside)
    for key, value, size in (("x0_px", camera.x0_px, camera.width_px), ("y0_px", camera.y0_px, camera.height_px)):
        if not -0.5 <= value <= size - 0.5:
            raise ShipstarError(f"{where}: field {key!r} must lie on the sensor, within [-0.5, {size - 0.5:g}] px, "
                                f"got {value:g}")
    return camera


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ShipstarError(f"cannot write the non-finite number {value!r} to a camera file")
        return repr(value)            # shortest string that reads back to the same double
    if isinstance(value, str):
        # JSON escapes are valid TOML basic-string escapes; TOML also wants DEL escaped
        return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")
    raise ShipstarError(f"cannot write {type(value).__name__} {value!r} to a camera file")


def camera_to_toml_text(camera: Camera) -> str:
    """The camera as TOML text (reads back to an equal :class:`Camera`)."""
    d = camera.as_dict()
    lines = ["# shipstar camera file (docs/camera.md)"]
    lines += [f"{k} = {_toml_value(d[k])}" for k in _CAMERA_KEYS]
    lines += ["", "[distortion]"]
    lines += [f"{k} = {_toml_value(v)}" for k, v in d["distortion"].items()]
    return "\n".join(lines) + "\n"


def save_camera(camera: Camera, path) -> None:
    """Write ``camera`` to a TOML file (atomically: never a half-written file)."""
    if not isinstance(camera, Camera):
        raise ShipstarError(f"save_camera needs a Camera, got {type(camera).__name__}")
    text = camera_to_toml_text(camera)
    from shipstar._atomic import atomic_write_text

    atomic_write_text(path, text, what="camera file")


@functools.lru_cache(maxsize=None)
def _preset(name: str) -> Camera:
    from importlib.resources import files

    resource = files("shipstar").joinpath("data", "cameras", f"{name}.toml")
    return camera_from_toml_text(resource.read_text(encoding="utf-8"), f"<preset {name}>")


def _preset_name(name: str) -> str | None:
    for preset in PRESETS:
        if preset.lower() == name.strip().lower():
            return preset
    return None


def camera_preset(name: str) -> Camera:
    """A packaged camera: ``"A1"``, ``"A2"`` (seed 000), ``"seed002"``, ``"seed004"``
    (case-insensitive)."""
    canonical = _preset_name(name) if isinstance(name, str) else None
    if canonical is None:
        raise ShipstarError(f"no camera preset {name!r} (presets: {', '.join(PRESETS)})")
    return _preset(canonical)


def load_camera(path_or_name) -> Camera:
    """A camera from a TOML file, or a preset name (see :func:`camera_preset`).

    A bare name that matches a preset (no directory part, no ``.toml``) is the preset;
    anything else is a file path.
    """
    if isinstance(path_or_name, str):
        canonical = _preset_name(path_or_name)
        if canonical is not None and os.sep not in path_or_name and not path_or_name.endswith(".toml"):
            return _preset(canonical)
    if not isinstance(path_or_name, (str, os.PathLike)):
        raise ShipstarError(f"camera must be a file path or a preset name, got {path_or_name!r}")
    path = Path(path_or_name)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ShipstarError(f"no camera file {str(path)!r} (and not a preset: {', '.join(PRESETS)})") from None
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
        raise ShipstarError(f"cannot read camera file {str(path)!r}: {_one_line(reason)}") from None
    return camera_from_toml_text(text, str(path))
