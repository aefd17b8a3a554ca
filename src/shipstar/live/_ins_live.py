"""``shipstar live --ins-udp PORT``: the ship's INS over UDP, corrected by the stars as they
come (the forward filter, :class:`shipstar.pipeline._ins.ForwardIns`), published at the
INS's rate with method ``stars+ins`` (issue 15 item 4).

A background thread receives datagrams (NMEA 0183: ``$--ZDA``, ``$PASHR``, ``$--HDT``,
``$PSXN,23``, as :mod:`shipstar.live._ins_input` reads a recorded log; signs from
``--ins-convention``) and queues the INS records.  The live loop (:meth:`LiveIns.poll`)
runs them through the filter and sends each corrected record on the UDP outputs: NMEA
``$PSSTA`` (method ``stars+ins`` or ``ins-bridged``, stars 0), ``$HEHDT``, ``$PASHR``; JSON
lines ``{"kind": "ins", "time_utc", "heading_deg", ..., "source", "method": "stars+ins"}``.
Each joint star epoch the engine gives out (:meth:`LiveIns.star`) updates the filter.
Bad sentences and records are counted and reported in one line each (the first 20).
"""

from __future__ import annotations

import json
import queue
import socket
import threading

from shipstar.errors import ShipstarError
from shipstar.units import DAY_S, RAD2DEG

__all__ = ["LiveIns"]


class LiveIns:
    """The INS receiver and forward filter of a live run.

    Parameters
    ----------
    host : str
    port : int
        0 picks a free one (:attr:`port` after :meth:`start`).
    convention : str
    origin_utc_jd : (float, float)
        Time origin of the filter (the run's start); a PASHR before any ZDA takes the day
        nearest it.
    on_error : callable(str), optional
    """

    def __init__(self, host: str, port: int, convention: str = "", *, origin_utc_jd, on_error=None, model=None):
        from shipstar.frames import AttitudeConvention
        from shipstar.live._ins_input import NmeaRecords, _Collector
        from shipstar.pipeline._ins import ForwardIns

        if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
            raise ShipstarError(f"--ins-udp port must be 0-65535, got {port!r}")
        self.host, self._port = str(host), port
        self.origin = (float(origin_utc_jd[0]), float(origin_utc_jd[1]))
        self.on_error = on_error
        self.records: queue.Queue = queue.Queue()
        self._col = _Collector(f"UDP {host}:{port}", self.origin, sink=lambda t, a: self.records.put((t, a)),
                               convention=AttitudeConvention(convention))
        self._nmea = NmeaRecords(self._col)
        self.filter = ForwardIns(model)
        self._sock = None
        self._thread = None
        self._stop = threading.Event()
        self._reported = 0
        self.n_datagrams = 0
        self.n_published = 0
        self.n_bridged = 0

    @property
    def port(self) -> int:
        return self._sock.getsockname()[1] if self._sock is not None else self._port

    def start(self) -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind((self.host, self._port))
        except OSError as exc:
            sock.close()
            raise ShipstarError(f"--ins-udp {self.host}:{self._port}: cannot listen: {exc.strerror or exc}") from None
        sock.settimeout(0.2)
        self._sock = sock
        self._thread = threading.Thread(target=self._receive, name="shipstar-ins-udp", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        if self._sock is not None:
            self._sock.close()

    def _receive(self) -> None:
        while not self._stop.is_set():
            try:
                data = self._sock.recv(65535)
            except socket.timeout:
                continue
            except OSError:
                return
            self.n_datagrams += 1
            for k, line in enumerate(data.decode("latin-1").splitlines()):
                self._nmea.feed(line, f"datagram {self.n_datagrams} sentence {k + 1}")
            self._report_problems()

    def _report_problems(self) -> None:
        while self._reported < len(self._col.problems):
            if self.on_error is not None:
                self.on_error(self._col.problems[self._reported])
            self._reported += 1

    # -- the live loop's side --------------------------------------------------------------------
    def star(self, emission) -> None:
        """A joint star epoch from the engine."""
        e = getattr(emission, "epoch", None)
        if e is None or not e.joint.solved:
            return
        t = ((e.utc_jd1 - self.origin[0]) + (e.utc_jd2 - self.origin[1])) * DAY_S
        self.filter.add_star(t, (e.joint.heading_rad, e.joint.pitch_rad, e.joint.roll_rad), e.joint.covariance_rad2)

    def poll(self, udp=None) -> list:
        """Run the records received through the filter; send each on ``udp`` (a
        :class:`~shipstar.live._outputs.UdpOutput`); returns ``[(t_s, angles_rad, sigma_arcsec, bridged)]``."""
        out = []
        while True:
            try:
                t, a = self.records.get_nowait()
            except queue.Empty:
                break
            try:
                rec = self.filter.add_record(t, a)
            except ShipstarError as exc:
                if self.on_error is not None:
                    self.on_error(f"INS {exc}")
                continue
            out.append(rec)
            self.n_published += 1
            self.n_bridged += bool(rec[3])
            if udp is not None:
                udp._send(self.message(rec, udp.fmt).encode("ascii"))
        return out

    def message(self, rec, fmt: str) -> str:
        """One corrected record as NMEA (``$PSSTA``, ``$HEHDT``, ``$PASHR``) or a JSON line."""
        from shipstar.live import _nmea
        from shipstar.sky.time import iso_from_utc_jd

        t, a, sig, bridged = rec
        jd1, jd2 = self.origin[0], self.origin[1] + t / DAY_S
        h, p, r = (float(x) * RAD2DEG for x in a)
        source = "ins-bridged" if bridged else "stars+ins"
        if fmt == "jsonl":
            return json.dumps({"kind": "ins", "time_utc": iso_from_utc_jd(jd1, jd2, 6), "method": "stars+ins",
                               "heading_deg": h, "pitch_deg": p, "roll_deg": r,
                               "sigma_heading_arcsec": float(sig[0]), "sigma_pitch_arcsec": float(sig[1]),
                               "sigma_roll_arcsec": float(sig[2]), "source": source}) + "\n"
        text = _nmea.pssta(jd1, jd2, h, p, r, float(sig[0]), float(sig[1]), float(sig[2]), source, 0, True)
        text += _nmea.hehdt(h)
        status = _nmea.PASHR_S_DEGRADED if bridged else _nmea.PASHR_S_NOMINAL
        text += _nmea.pashr(jd1, jd2, h, r, p, sig[2] / 3600.0, sig[1] / 3600.0, sig[0] / 3600.0,
                            _nmea.PASHR_Q_FUSED, status)
        return text

    def summary(self) -> dict:
        """``ins`` (the current estimate: biases now, not at the first record) and counts."""
        s = self.filter.summary()
        return {**s, "n_records": self.filter.n_records, "n_published": self.n_published,
                "n_bridged": self.n_bridged, "n_star_updates": self.filter.n_updates,
                "n_records_skipped": self._col.n_skipped, "n_datagrams": self.n_datagrams}

    def __repr__(self) -> str:
        return f"LiveIns({self.host}:{self.port})"
