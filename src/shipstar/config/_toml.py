"""Reading the TOML project files: typed tables with named, one-line errors.

Every reader in :mod:`shipstar.config` goes through :func:`_read_toml` (format name and
version checked) and :class:`_Table` (typed keys, ranges, unknown keys refused), so an
error always names the file, the table and the key.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

from shipstar.errors import ShipstarError

FORMAT_VERSION = 1
_REQUIRED = object()


class _Table:
    """Typed access to one TOML table; :meth:`finish` refuses keys nobody asked for."""

    def __init__(self, data, where: str):
        if not isinstance(data, dict):
            raise ShipstarError(f"{where} must be a table")
        self.data, self.where, self.used = data, where, set()

    def _get(self, key: str, default):
        self.used.add(key)
        if key not in self.data:
            if default is _REQUIRED:
                raise ShipstarError(f"{self.where}: missing key {key!r}")
            return default, False
        return self.data[key], True

    def number(self, key: str, default=_REQUIRED, *, lo=-math.inf, hi=math.inf, lo_open=False,
               limit: str | None = None) -> float:
        """A finite number; a ``*_deg`` key may be a string in degrees-minutes-seconds
        (``"46d28m28.51s"``, ``"46:28:28.51"``).  ``limit`` names its physical range in
        :data:`shipstar.limits.RANGES` (the one set of every entry point) instead of ``lo``/``hi``."""
        value, given = self._get(key, default)
        if not given:
            return value
        if isinstance(value, str) and key.endswith("_deg"):
            from shipstar.limits import parse_angle_deg

            try:
                value = parse_angle_deg(value)
            except ShipstarError:
                raise ShipstarError(f"{self.where}: {key} must be a finite number or degrees-minutes-seconds "
                                    f"(\"46d28m28.51s\", \"46:28:28.51\"), got {value!r}") from None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ShipstarError(f"{self.where}: {key} must be a finite number, got {value!r}")
        if limit is not None:
            from shipstar.limits import check_range

            return check_range(limit, value, label=key, where=self.where)
        if value < lo or value > hi or (lo_open and value == lo):
            op = ">" if lo_open else ">="
            rng = f"{op} {lo:g}" if hi == math.inf else f"within [{lo:g}, {hi:g}]"
            raise ShipstarError(f"{self.where}: {key} must be {rng}, got {value!r}")
        return float(value)

    def integer(self, key: str, default=_REQUIRED, *, lo=0, hi=2**63 - 1) -> int:
        value, given = self._get(key, default)
        if not given:
            return value
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise ShipstarError(f"{self.where}: {key} must be an integer within [{lo}, {hi}], got {value!r}")
        return int(value)

    def text(self, key: str, default=_REQUIRED, *, choices=None) -> str:
        value, given = self._get(key, default)
        if not given:
            return value
        if not isinstance(value, str):
            raise ShipstarError(f"{self.where}: {key} must be a string, got {value!r}")
        if choices is not None and value not in choices:
            raise ShipstarError(f"{self.where}: {key} must be one of {', '.join(choices)}, got {value!r}")
        return value

    def table(self, key: str, required: bool = False) -> "_Table | None":
        value, given = self._get(key, _REQUIRED if required else None)
        return _Table(value, f"{self.where} [{key}]") if given else None

    def tables(self, key: str) -> list:
        value, given = self._get(key, [])
        if given and not (isinstance(value, list) and all(isinstance(v, dict) for v in value)):
            raise ShipstarError(f"{self.where}: {key} must be an array of tables [[{key}]]")
        return [_Table(v, f"{self.where} [[{key}]] #{k + 1}") for k, v in enumerate(value)]

    def finish(self) -> None:
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            raise ShipstarError(f"{self.where}: unknown key {unknown[0]!r}")


def _read_toml(path, what: str) -> tuple[Path, _Table]:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ShipstarError(f"{what} file {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ShipstarError(f"cannot read {what} file {path}: {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ShipstarError(f"{path}: not valid TOML: {' '.join(str(exc).split())}") from None
    t = _Table(data, str(path))
    fmt = t.text("format")
    if fmt != f"shipstar-{what}":
        raise ShipstarError(f"{path}: format must be 'shipstar-{what}', got {fmt!r}")
    version = t.integer("format_version")
    if version != FORMAT_VERSION:
        raise ShipstarError(f"{path}: format_version {version} is not supported (expected {FORMAT_VERSION})")
    return path, t


def _relative(base: Path, name: str) -> Path:
    p = Path(name).expanduser()
    return p if p.is_absolute() else base.parent / p
