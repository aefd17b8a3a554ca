"""What ``shipstar live`` sends out over UDP: attitude rows as JSON lines or NMEA 0183
sentences, and a status message every second (docs/file-formats.md, *Live outputs*).

- ``jsonl``: one datagram per attitude row of every method, a JSON object whose keys are
  exactly the attitude CSV's columns (numbers as JSON numbers, empty as null); the status
  is an object with ``"kind": "status"`` (attitude rows have no ``kind`` key).
- ``nmea``: one datagram per epoch holding, CRLF-terminated and in this order, ``$PSSTA``
  (full precision, A or V), ``$HEHDT`` (only when valid) and ``$PASHR``, for the method
  chosen (``joint``, ``seed-rule``, or ``single``: the reference sensor's own frame); the
  status is a ``$PSSTS`` sentence.
"""

from __future__ import annotations

import json
import math
import socket

from shipstar.errors import ShipstarError
from shipstar.units import RAD2ASEC, RAD2DEG

__all__ = ["FORMATS", "METHODS", "UdpOutput", "row_objects", "epoch_sentences", "parse_host_port",
           "resolve_udp_destination"]

FORMATS = ("jsonl", "nmea")
METHODS = ("joint", "seed-rule", "single")
_INT_COLUMNS = ("solved", "n_stars")
_TEXT_COLUMNS = ("time_utc", "method", "sensor", "frame", "reason", "time_source", "integrity", "suspect_sensor")


def parse_host_port(text: str, *, default_host: str | None = None) -> tuple[str, int]:
    """``HOST:PORT`` (or ``PORT`` with a ``default_host``) -> ``(host, port)``.

    Raises
    ------
    ShipstarError
        Not of that form, or a port outside 1-65535.
    """
    host, sep, port = str(text).rpartition(":")
    if not sep:
        host, port = default_host, text
    if not host:
        raise ShipstarError(f"expected HOST:PORT, got {text!r}")
    try:
        number = int(port)
    except ValueError:
        raise ShipstarError(f"port must be a number in 1-65535, got {port!r} in {text!r}") from None
    if not 1 <= number <= 65535:
        raise ShipstarError(f"port must be in 1-65535, got {number} in {text!r}")
    return host, number


def resolve_udp_destination(host: str, port: int) -> tuple[str, int]:
    """``(IPv4 address, port)`` of a UDP destination, its name looked up once, at the start:
    a host that cannot be resolved is a one-line ShipstarError there (it was every
    datagram's lost send, counted but silent), and no datagram waits for a name lookup."""
    try:
        info = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)
    except socket.gaierror as exc:
        raise ShipstarError(f"UDP destination {host}:{port}: the host cannot be resolved "
                            f"({exc.strerror or exc})") from None
    return info[0][4][0], int(port)


def row_objects(rows) -> list:
    """CSV rows (lists of str, :data:`~shipstar.pipeline.ATTITUDE_COLUMNS` order) -> dicts
    with numbers as numbers and empty fields as None."""
    from shipstar.pipeline import ATTITUDE_COLUMNS

    out = []
    for row in rows:
        obj = {}
        for col, text in zip(ATTITUDE_COLUMNS, row):
            if text == "":
                obj[col] = None
            elif col in _TEXT_COLUMNS:
                obj[col] = text
            elif col in _INT_COLUMNS:
                obj[col] = int(text)
            else:
                obj[col] = float(text)
        out.append(obj)
    return out


def _method_attitude(emission, method: str, reference_sensor: str):
    """``(ShipAttitude, method name)`` of an emission for the NMEA output, or None."""
    e = emission.epoch
    if e is None:
        return None
    if method == "joint":
        return e.joint, "joint"
    if method == "seed-rule":
        return e.seed_rule, "seed-rule"
    ref = next((fr for fr in emission.frames if fr.sensor == reference_sensor and fr.label == e.label), None)
    return (ref.ship, "single") if ref is not None else None


def epoch_sentences(emission, method: str, reference_sensor: str, *, degraded: bool = False) -> str:
    """The NMEA datagram of one emission (``$PSSTA``, ``$HEHDT`` when valid, ``$PASHR``), or
    '' when it has no epoch of that method."""
    from shipstar.live import _nmea

    picked = _method_attitude(emission, method, reference_sensor)
    if picked is None:
        return ""
    att, name = picked
    e = emission.epoch
    ok = bool(att.solved)
    h, p, r = (att.heading_rad * RAD2DEG, att.pitch_rad * RAD2DEG, att.roll_rad * RAD2DEG) if ok else (math.nan,) * 3
    sig = att.sigma_rad * RAD2ASEC if ok else [math.nan] * 3
    text = _nmea.pssta(e.utc_jd1, e.utc_jd2, h, p, r, sig[0], sig[1], sig[2], name, int(att.n_stars), ok)
    if ok:
        text += _nmea.hehdt(h)
    quality = (_nmea.PASHR_Q_SINGLE if name == "single" else _nmea.PASHR_Q_FUSED) if ok else _nmea.PASHR_Q_NONE
    status = (_nmea.PASHR_S_DEGRADED if degraded else _nmea.PASHR_S_NOMINAL) if ok else _nmea.PASHR_S_NONE
    text += _nmea.pashr(e.utc_jd1, e.utc_jd2, h, r, p, sig[2] / 3600.0, sig[1] / 3600.0, sig[0] / 3600.0,
                        quality, status)
    return text


class UdpOutput:
    """Datagrams to one or more ``(host, port)`` destinations.

    Parameters
    ----------
    destinations : sequence of (str, int)
    fmt : {"jsonl", "nmea"}
    method : {"joint", "seed-rule", "single"}
        The attitude the NMEA sentences carry.
    sensors : sequence of str
        The session's sensors in order (fused rows with two or more).
    reference_sensor : str
    """

    def __init__(self, destinations, fmt: str, method: str, sensors, reference_sensor: str):
        if fmt not in FORMATS:
            raise ShipstarError(f"unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")
        if method not in METHODS:
            raise ShipstarError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
        self.destinations = [tuple(d) for d in destinations]
        self.fmt, self.method = fmt, method
        self.sensors, self.reference_sensor = tuple(sensors), reference_sensor
        self.n_sent = 0
        self.n_errors = 0
        self.last_error = ""
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    def _send(self, data: bytes) -> None:
        for dest in self.destinations:
            try:
                self._sock.sendto(data, dest)
                self.n_sent += 1
            except OSError as exc:            # a receiver that is not there yet: count, go on
                self.n_errors += 1
                self.last_error = f"UDP {dest[0]}:{dest[1]}: {exc.strerror or exc}"

    def emission(self, emission, start_utc_jd, *, degraded: bool = False) -> None:
        """Send one emission's rows (jsonl) or its epoch's sentences (nmea)."""
        from shipstar.pipeline._output import emission_rows

        if self.fmt == "jsonl":
            for obj in row_objects(emission_rows(emission, self.sensors, start_utc_jd)):
                self._send((json.dumps(obj, allow_nan=False) + "\n").encode("ascii"))
        else:
            text = epoch_sentences(emission, self.method, self.reference_sensor, degraded=degraded)
            if text:
                self._send(text.encode("ascii"))

    def status(self, status: dict, health, utc_jd, eop: dict | None) -> None:
        """Send the once-a-second status: ``status`` as JSON, or ``$PSSTS`` from ``health``
        (sequence of :class:`shipstar.live._nmea.SensorHealth`) at ``utc_jd``."""
        from shipstar.live import _nmea

        if self.fmt == "jsonl":
            self._send((json.dumps({"kind": "status", **status}, allow_nan=False) + "\n").encode("ascii"))
        else:
            eop = eop or {}
            self._send(_nmea.pssts(utc_jd[0], utc_jd[1], health, eop.get("quality"),
                                   eop.get("dut1_error_s")).encode("ascii"))

    def close(self) -> None:
        self._sock.close()
