"""Star sensor calibration.

- :mod:`shipstar.calibrate.intrinsics`: focal length, principal point and Weng
  distortion from star frames alone (seed 002; docs/calibration-intrinsic.md).
- :mod:`shipstar.calibrate.installation`: installation angles of a sensor on the deck
  from dock frames (seed 000).

Import the submodule you need; this package imports nothing heavy.
"""
