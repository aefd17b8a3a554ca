"""Star sensor camera model: pinhole + Weng distortion, photometry, presets and files.

Public API::

    Camera, Distortion                       # frozen dataclasses (validated)
    camera.project(v_sensor) -> xy_px        # (..., 3) -> (..., 2), NaN behind the lens
    camera.unproject(xy_px) -> v_sensor      # (..., 2) -> (..., 3) unit vectors
    camera.in_image(xy_px, margin_px=0.0)
    camera_preset(name)                      # "A1", "A2", "seed002", "seed004"
    load_camera(path_or_name), save_camera(camera, path)
    sky_e_per_px_per_s(camera, sky_mag_per_arcsec2)

Conventions (docs/conventions.md, docs/camera.md): x right along a row, y down, the
top-left pixel centre at (0, 0); sensor frame X boresight, Y image up, Z image right;
distortion maps ideal -> observed focal-plane offsets in mm.
"""

from __future__ import annotations

from shipstar.camera._distortion import Distortion
from shipstar.camera._files import PRESETS, camera_preset, load_camera, save_camera
from shipstar.camera._model import Camera, sky_e_per_px_per_s

__all__ = ["Camera", "Distortion", "PRESETS", "camera_preset", "load_camera", "save_camera",
           "sky_e_per_px_per_s"]
