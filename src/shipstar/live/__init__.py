"""Live shipboard operation: frames as they arrive, navigation and weather from the ship,
attitude out to the ship's systems (docs/live.md).

Drivers of the streaming engine (:mod:`shipstar.pipeline`) and their I/O:

- ``_nmea``: NMEA 0183 sentences, out (``$PSSTA``, ``$HEHDT``, ``$PASHR``, ``$PSSTS``) and in
  (GGA, RMC, ZDA, MDA, XDR), checksums;
- ``_nav``: the ship's position, time and weather while live (NMEA over UDP, growing CSV
  files), as tables the engine reads;
- ``_replay``: a recorded or simulated session written into per-sensor directories at its
  real time spacing (``shipstar replay``);
- ``_http``: the read-only operator console, a web page fed by server-sent events
  (``shipstar live --http``; its page, script and style in ``console/``);
- ``_cdp``: a headless Chromium driven over the DevTools protocol pipe (the console's
  browser test, its screenshot and its benchmark).

Nothing here is imported by ``import shipstar``.
"""

from __future__ import annotations

__all__: list = []
