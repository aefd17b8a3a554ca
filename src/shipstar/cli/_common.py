"""Helpers shared by the sub-commands: argument types that validate at the edge, output
paths checked before any work, the accuracy warnings of a run, JSON out."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

from shipstar.errors import ShipstarError

__all__ = ["finite_float", "angle_deg", "in_range", "latitude_deg", "longitude_deg", "deflection_arcsec", "fraction", "positive_float",
           "int_in_range", "float_in_range", "rng_seed", "add_site_arguments", "add_weather_arguments", "add_windowed_argument", "WINDOWED_HELP",
           "add_refraction_arguments", "add_date_obs_is_argument", "REFRACTION_MODELS", "emit_json", "atomic_write_text", "check_output_file", "check_output_dir", "check_outputs_apart", "check_folders_apart", "resolved_path", "accuracy_warnings",
           "one_line"]


def atomic_write_text(path, text: str, *, newline: str | None = None, what: str = "") -> Path:
    """:func:`shipstar._atomic.atomic_write_text`, imported on first use (its ``tempfile``
    is not needed by ``shipstar solve``)."""
    from shipstar._atomic import atomic_write_text as write

    return write(path, text, newline=newline, what=what)


def finite_float(text: str) -> float:
    """argparse type: a finite float (rejects NaN and inf with a one-line message)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return value


def angle_deg(text: str) -> float:
    """argparse type: an angle in degrees, decimal (``46.474586``) or degrees-minutes-seconds
    (``46d28m28.51s``, ``46:28:28.51``, ``-46d28m28.51s``): :func:`shipstar.limits.parse_angle_deg`."""
    from shipstar.limits import parse_angle_deg

    try:
        return parse_angle_deg(text)
    except ShipstarError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def in_range(name: str, *, angle: bool | None = None, label: str | None = None):
    """argparse type factory: a value within the physical range ``shipstar.limits.RANGES[name]``
    (one set for every entry point), refused in one line naming the value, the range and its
    reason.  Ranges whose name ends in ``_deg`` (or ``angle=True``) also take degrees-minutes-seconds."""
    is_angle = name.endswith("_deg") if angle is None else angle

    def parse(text: str) -> float:
        from shipstar.limits import check_range

        value = angle_deg(text) if is_angle else finite_float(text)
        try:
            return check_range(name, value, label=label)
        except ShipstarError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parse.__name__ = name
    return parse


#: argparse type: geodetic latitude (deg, decimal or DMS) within [-90, 90].
latitude_deg = in_range("lat_deg", label="latitude")
#: argparse type: longitude (deg, decimal or DMS) within [-180, 360] (east positive, or 0-360).
longitude_deg = in_range("lon_deg", label="longitude")


def deflection_arcsec(text: str) -> float:
    """argparse type: a deflection of the vertical component (arcsec) within +-120."""
    from shipstar.sky.apparent import MAX_DEFLECTION_ARCSEC

    value = finite_float(text)
    if abs(value) > MAX_DEFLECTION_ARCSEC:
        raise argparse.ArgumentTypeError(f"must be within +-{MAX_DEFLECTION_ARCSEC:g} arcsec, got {value}")
    return value


def fraction(text: str) -> float:
    """argparse type: a number within [0, 1] (e.g. relative humidity)."""
    value = finite_float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"must be within [0, 1], got {value}")
    return value


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    value = finite_float(text)
    if value <= 0.0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {value}")
    return value


def _range_text(lo, hi, shown) -> str:
    if shown is not None:
        return f"must be within {shown}"
    return f"must be >= {lo:g}" if hi is None else f"must be within {lo}..{hi}"


def int_in_range(lo: int, hi: int | None = None, shown: str | None = None):
    """argparse type factory: an integer within ``[lo, hi]`` (``hi`` None: no upper bound).

    ``shown`` words the range in the error message (default ``"lo..hi"``, or ``">= lo"``
    without ``hi``): ``must be within {shown}, got {value}``.
    """
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
        if value < lo or (hi is not None and value > hi):
            raise argparse.ArgumentTypeError(f"{_range_text(lo, hi, shown)}, got {value}")
        return value

    return parse


def float_in_range(lo: float, hi: float | None = None, shown: str | None = None, *, angle: bool = False):
    """argparse type factory: a finite float within ``[lo, hi]`` (``hi`` None: no upper
    bound); ``shown`` as in :func:`int_in_range`; ``angle``: degrees, decimal or DMS
    (:func:`angle_deg`)."""
    def parse(text: str) -> float:
        value = angle_deg(text) if angle else finite_float(text)
        if value < lo or (hi is not None and value > hi):
            raise argparse.ArgumentTypeError(f"{_range_text(lo, hi, shown)}, got {value}")
        return value

    return parse


#: argparse type: a random-number seed, 0 .. 2**63-1.
rng_seed = int_in_range(0, 2**63 - 1, "0..2**63-1")


# ---------------------------------------------------------------------------------------
# Argument groups shared by the commands (each command words the help for its context)
# ---------------------------------------------------------------------------------------

REFRACTION_MODELS = ("erfa", "almanac", "none")


def add_site_arguments(parser, helps: dict, *, required: bool = False, deflection: bool = True,
                       deflection_default=0.0) -> None:
    """Add ``--lat-deg``, ``--lon-deg``, ``--height-m`` (default 0) and, with ``deflection``,
    ``--xi-arcsec``/``--eta-arcsec``; ``helps`` maps each dest (``lat_deg``, ...) to its help."""
    parser.add_argument("--lat-deg", required=required, type=latitude_deg, help=helps["lat_deg"])
    parser.add_argument("--lon-deg", required=required, type=longitude_deg, help=helps["lon_deg"])
    parser.add_argument("--height-m", type=finite_float, default=0.0, help=helps["height_m"])
    if deflection:
        parser.add_argument("--xi-arcsec", type=deflection_arcsec, default=deflection_default,
                            help=helps["xi_arcsec"])
        parser.add_argument("--eta-arcsec", type=deflection_arcsec, default=deflection_default,
                            help=helps["eta_arcsec"])


def add_weather_arguments(parser, helps: dict, *, required: bool = False, humidity_default=0.0) -> None:
    """Add ``--pressure-hpa``, ``--temperature-c`` and ``--relative-humidity`` (0..1);
    ``helps`` maps each dest to its help."""
    parser.add_argument("--pressure-hpa", required=required, type=in_range("pressure_hpa"), help=helps["pressure_hpa"])
    parser.add_argument("--temperature-c", required=required, type=in_range("temperature_c"),
                        help=helps["temperature_c"])
    parser.add_argument("--relative-humidity", type=in_range("relative_humidity"), default=humidity_default,
                        help=helps["relative_humidity"])


def add_refraction_arguments(parser, model_help: str, mode_help: str | None = None, *,
                             default: str | None = "erfa") -> None:
    """Add ``--refraction`` (erfa, almanac, none) and, with ``mode_help``, ``--refraction-mode``
    (per-star, the default, or boresight)."""
    parser.add_argument("--refraction", choices=REFRACTION_MODELS, default=default, help=model_help)
    if mode_help is not None:
        parser.add_argument("--refraction-mode", choices=("per-star", "boresight"), default="per-star",
                            help=mode_help)


DATE_OBS_IS_HELP = ("what the frames' DATE-OBS means: start of the exposure (FITS standard, default) or "
                    "mid-exposure (cameras that write it so)")


def add_date_obs_is_argument(parser, help: str = DATE_OBS_IS_HELP) -> None:
    """Add ``--date-obs-is`` (start, the FITS standard and default, or mid)."""
    parser.add_argument("--date-obs-is", choices=("start", "mid"), default="start", help=help)


def emit_json(obj, stream=None) -> None:
    """Print one JSON object (NaN is refused: it is not JSON)."""
    stream = sys.stdout if stream is None else stream
    try:
        text = json.dumps(obj, allow_nan=False)
    except ValueError as exc:
        raise ShipstarError(f"result is not finite, refusing to print it as JSON: {exc}") from None
    stream.write(text + "\n")


# ---------------------------------------------------------------------------------------
# Output paths: checked before processing, so that a bad path never costs a whole run
# ---------------------------------------------------------------------------------------

def _writable_ancestor(path: Path, flag: str, shown: Path) -> None:
    """The nearest existing ancestor of ``path`` must be a directory we may write in."""
    p = path
    while not p.exists() and p != p.parent:
        p = p.parent
    p = p if p.exists() else Path(".")
    if not p.is_dir():
        raise ShipstarError(f"{flag} {shown}: {p} is a file, not a directory")
    if not os.access(p, os.W_OK | os.X_OK):
        raise ShipstarError(f"{flag} {shown}: no permission to write in {p}")


def check_output_file(path, flag: str) -> Path:
    """Refuse (ShipstarError) an output file path that cannot be written.

    The path must not be a directory, and its nearest existing parent must be a
    directory we may write in (missing directories are created when writing).
    """
    p = Path(path)
    if str(path).strip() == "" or p.name in ("", ".", ".."):
        raise ShipstarError(f"{flag} {str(path)!r} is not a file name")
    if p.is_dir():
        raise ShipstarError(f"{flag} {p} is a directory, expected a file name")
    _writable_ancestor(p.parent, flag, p)
    return p


def check_output_dir(path, flag: str, files=()) -> Path:
    """Refuse (ShipstarError) an output directory that cannot be created or written, or
    in which one of ``files`` (names) could not be written."""
    p = Path(path)
    if str(path).strip() == "":
        raise ShipstarError(f"{flag} needs a directory name")
    if p.exists() and not p.is_dir():
        raise ShipstarError(f"{flag} {p} exists and is not a directory")
    _writable_ancestor(p, flag, p)
    for name in files:
        check_output_file(p / name, flag)
    return p


#: ``args`` attributes naming the files a command reads, and their flags (None: the
#: positional inputs; a value: a path, a ``(name, path)`` pair or a list of either)
_INPUT_FILES = (("track", "--track"), ("weather", "--weather"), ("install", "--install"), ("truth", "--truth"),
                ("ins", "--ins"), ("ins_truth", "--ins-truth"), ("eop", "--eop"), ("camera", "--camera"),
                ("inputs", None))
#: ``args`` attributes naming the folders of frames a command reads, and their flags
_INPUT_FOLDERS = (("sensor", "--sensor"), ("frames", "--frames"), ("session", "--session"))


def _paths(value) -> list:
    """The paths a flag's value names: a path, a ``(name, path)`` pair, or a list of them
    (a value of another kind, a flag of the same name that is not a path, names none)."""
    if isinstance(value, tuple) and len(value) == 2 and isinstance(value[0], str):
        return _paths(value[1])
    if isinstance(value, (list, tuple)):
        return [p for v in value for p in _paths(v)]
    return [value] if isinstance(value, (str, os.PathLike)) and str(value) != "" else []


def resolved_path(path) -> Path:
    """``path`` absolute, ``~`` expanded, symbolic links followed: where two spellings of
    one file compare equal."""
    return Path(os.path.abspath(os.path.expanduser(os.fspath(path)))).resolve()


def check_folders_apart(args) -> None:
    """Refuse (ShipstarError, one line) two sensors reading one folder of frames
    (``--sensor A1=d --sensor A2=d``): their frames would be one sensor's twice, caught
    today only where the frames carry a SENSOR card."""
    seen = {}
    for attr, flag in _INPUT_FOLDERS[:2]:                   # --sensor, --frames: NAME=DIR pairs
        value = getattr(args, attr, None)
        if not isinstance(value, list):
            continue
        for item in value:
            if not (isinstance(item, tuple) and len(item) == 2):
                continue
            name, folder = item
            real = resolved_path(folder)
            if real in seen and seen[real][0] != name:
                raise ShipstarError(f"{flag} {seen[real][0]} and {flag} {name} read the same folder {folder}: "
                                    f"each sensor needs its own")
            seen.setdefault(real, (name, folder))


def check_outputs_apart(args, outputs) -> None:
    """Refuse (ShipstarError, one line), before any work, an output that would overwrite
    what the command reads or another of its outputs.

    Parameters
    ----------
    args : argparse.Namespace
        The command's arguments: its inputs are the existing files and frame folders of
        the flags in :data:`_INPUT_FILES` and :data:`_INPUT_FOLDERS` it has.
    outputs : sequence of (flag, path, names)
        Each output: a file (``names`` None) or a folder the command writes the files
        ``names`` in; a ``path`` of None is not given.

    An output is refused when it is one of the input files, when it is a file with a
    frame's name (``*.fits`` ...) in a folder of frames, when it is another output's file,
    or when a file output is another output's folder.
    """
    from shipstar._fitsio import is_fits_name

    files, folders = [], []                         # (flag, shown, resolved path)
    for flag, path, names in outputs:
        if path is None or str(path) == "":
            continue
        if names is None:
            files.append((flag, path, resolved_path(path)))
        else:
            folders.append((flag, path, resolved_path(path)))
            files.extend((flag, Path(path) / name, resolved_path(Path(path) / name)) for name in names)
    inputs = {}
    for attr, flag in _INPUT_FILES:
        for p in _paths(getattr(args, attr, None)):
            if Path(p).is_file():
                inputs.setdefault(resolved_path(p), (flag, p))
    frame_dirs = {}
    for attr, flag in _INPUT_FOLDERS:
        for p in _paths(getattr(args, attr, None)):
            if Path(p).is_dir():
                frame_dirs.setdefault(resolved_path(p), (flag, p))
    seen = {}
    for flag, shown, real in files:
        if real in inputs:
            in_flag, in_path = inputs[real]
            what = "the" if in_flag is None else f"the {in_flag}"
            what += " input" if str(in_path) == str(shown) else f" input {in_path}"
            raise ShipstarError(f"{flag} {shown} is {what}: refusing to overwrite it")
        if is_fits_name(Path(shown).name) and real.parent in frame_dirs:
            in_flag, in_path = frame_dirs[real.parent]
            if real.exists():
                raise ShipstarError(f"{flag} {shown} is a frame of the {in_flag} folder {in_path}: refusing to "
                                    f"overwrite it")
            raise ShipstarError(f"{flag} {shown} would be a frame of the {in_flag} folder {in_path}: write it "
                                f"elsewhere")
        if real in seen and seen[real][0] != flag:
            raise ShipstarError(f"{seen[real][0]} and {flag} are the same file {shown}: give each its own")
        seen.setdefault(real, (flag, shown))
    for flag, shown, real in folders:
        if real in seen:
            raise ShipstarError(f"{seen[real][0]} {seen[real][1]} is the {flag} folder: give each its own")


# ---------------------------------------------------------------------------------------
# Warnings
# ---------------------------------------------------------------------------------------

def one_line(text) -> str:
    """A message on one line (runs of white space, newlines included, become one space)."""
    return " ".join(str(text).split())


def accuracy_warnings(args) -> list:
    """Distinct one-line messages of the :class:`~shipstar.errors.AccuracyWarning` s raised
    so far in this command (``shipstar.cli.main`` records them in ``args.caught_warnings``;
    empty when the command runs without it)."""
    from shipstar.errors import AccuracyWarning

    caught = getattr(args, "caught_warnings", None) or []
    return list(dict.fromkeys(one_line(w.message) for w in caught if issubclass(w.category, AccuracyWarning)))


WINDOWED_HELP = ("windowed tracking: measure a tracked frame's stars only in windows around their "
                 "predicted places, a full frame at least every N frames and whenever the windows find "
                 "too few stars (default 0: every frame whole; docs/pipeline.md, *Windowed tracking*)")


def add_windowed_argument(parser) -> None:
    """``--windowed-full-frame-every N`` (PipelineOptions.windowed_full_frame_every)."""
    parser.add_argument("--windowed-full-frame-every", type=int_in_range(0), default=0, metavar="N",
                        help=WINDOWED_HELP)
