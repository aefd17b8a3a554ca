"""The Moon and the Sun in a sensor's field: predicted and masked before extraction.

For each frame with a tracking prior (the J2000 attitude predicted from the sensor's last
solved frames), the Moon's and the Sun's topocentric places at the frame's time and the
ship's position (:func:`shipstar.sky.bodies.moon_sun`, recomputed every
:data:`RECOMPUTE_S` seconds: the Moon moves 0.5'' a second against the stars) are
projected into the image.  A body whose disc plus :func:`mask_radius_px`'s margin reaches
the image is masked: its pixels are replaced by the median of a ring just outside the
mask plus noise of the ring's robust scatter (a fixed seed), so the extraction's
background mesh sees sky and the scattered-light gradient outside the mask is taken by
the mesh; detections inside the mask are dropped.  The whole disc is masked, lit or not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shipstar.errors import ShipstarError

__all__ = ["BodyDisc", "BodyPredictor", "mask_bodies", "in_discs", "mask_radius_px", "RECOMPUTE_S"]

#: Body places are recomputed when the frame is further than this from the last (s).
RECOMPUTE_S = 10.0
#: Margin around a disc: fixed part (px) ...
MARGIN_PX = 15.0
#: ... plus this fraction of the disc's radius.
MARGIN_FRACTION = 0.25
#: Width of the ring whose median and scatter fill the mask (px).
RING_PX = 12.0


@dataclass(frozen=True)
class BodyDisc:
    """A body in (or beside) the field: ``name`` ("moon", "sun"), its centre ``xy_px`` (2,),
    its disc's radius and the masked radius (disc plus margin), px."""

    name: str
    xy_px: tuple
    disc_radius_px: float
    mask_radius_px: float


def mask_radius_px(disc_radius_px: float) -> float:
    """Masked radius for a disc of ``disc_radius_px``: the disc plus the margin."""
    return disc_radius_px * (1.0 + MARGIN_FRACTION) + MARGIN_PX


class BodyPredictor:
    """The Moon's and the Sun's discs in one camera's image (places cached)."""

    def __init__(self, camera):
        self.camera = camera
        self._t = None
        self._places = None

    def places(self, utc_jd1: float, utc_jd2: float, site):
        """:class:`~shipstar.sky.bodies.BodyPlaces` at the time (cached within RECOMPUTE_S)."""
        from shipstar.sky.apparent import frame_context
        from shipstar.sky.bodies import moon_sun
        from shipstar.sky.eop import earth_orientation

        if self._t is not None and abs((utc_jd1 - self._t[0]) + (utc_jd2 - self._t[1])) * 86400.0 < RECOMPUTE_S:
            return self._places
        ctx = frame_context(utc_jd1, utc_jd2, site, earth_orientation(utc_jd1, utc_jd2))
        self._t, self._places = (utc_jd1, utc_jd2), moon_sun(ctx)
        return self._places

    def discs(self, utc_jd1: float, utc_jd2: float, site, C_icrs_from_sensor, uncertainty_px: float = 0.0) -> tuple:
        """``(BodyDisc, ...)`` of the bodies whose masked disc (widened by the pointing's
        ``uncertainty_px``) reaches the image."""
        cam = self.camera
        places = self.places(utc_jd1, utc_jd2, site)
        C = np.asarray(C_icrs_from_sensor, float)
        scale_rad = cam.pixel_mm / cam.f_mm
        bodies = (("moon", places.moon_icrs, places.moon_radius_rad), ("sun", places.sun_icrs, places.sun_radius_rad))
        v = np.stack([C.T @ u for _, u, _ in bodies])            # (2, 3), each body as alone
        xy_all = cam.project(v)                                 # one call for both (the same per-row arithmetic)
        ok = (v[:, 0] > 0.0) & np.isfinite(xy_all).all(axis=1)
        out = []
        for (name, _, radius_rad), xy, good in zip(bodies, xy_all, ok.tolist()):
            if not good:
                continue
            r_disc = radius_rad / scale_rad
            r_mask = mask_radius_px(r_disc) + float(uncertainty_px)
            x, y = float(xy[0]), float(xy[1])
            dx = max(-0.5 - x, 0.0, x - (cam.width_px - 0.5))
            dy = max(-0.5 - y, 0.0, y - (cam.height_px - 0.5))
            if math.hypot(dx, dy) < r_mask:
                out.append(BodyDisc(name, (x, y), r_disc, r_mask))
        return tuple(out)


def _disc_box(shape, disc: BodyDisc, radius: float):
    h, w = shape
    x, y = disc.xy_px
    x0, x1 = max(int(math.floor(x - radius)), 0), min(int(math.ceil(x + radius)) + 1, w)
    y0, y1 = max(int(math.floor(y - radius)), 0), min(int(math.ceil(y + radius)) + 1, h)
    if x0 >= x1 or y0 >= y1:
        return None
    yy, xx = np.mgrid[y0:y1, x0:x1]
    return (slice(y0, y1), slice(x0, x1)), np.hypot(xx - x, yy - y)


def mask_bodies(image, discs) -> np.ndarray:
    """``image`` with each disc's masked pixels replaced by sky (see the module); the same
    array when there is nothing to mask, else a copy of the same dtype."""
    if not discs:
        return image
    out = np.array(image, copy=True)
    rng = np.random.default_rng(0)
    info = np.iinfo(out.dtype) if out.dtype.kind in "ui" else None
    for disc in discs:
        box = _disc_box(out.shape, disc, disc.mask_radius_px + RING_PX)
        if box is None:
            continue
        sl, r = box
        patch = out[sl]
        inside = r < disc.mask_radius_px
        ring = ~inside
        if not np.any(inside):
            continue
        if np.count_nonzero(ring) < 20:          # the image is all mask here: the frame's median
            level, spread = float(np.median(out)), 0.0
        else:
            vals = patch[ring].astype(float)
            level = float(np.median(vals))
            spread = 1.4826 * float(np.median(np.abs(vals - level)))
        fill = level + spread * rng.standard_normal(int(np.count_nonzero(inside)))
        if info is not None:
            fill = np.clip(np.rint(fill), info.min, info.max)
        patch[inside] = fill.astype(out.dtype)
    return out


def in_discs(xy_px, discs) -> np.ndarray:
    """``(N,)`` bool: positions inside any disc's masked radius."""
    xy = np.asarray(xy_px, float).reshape(-1, 2)
    out = np.zeros(len(xy), dtype=bool)
    for disc in discs:
        out |= np.hypot(xy[:, 0] - disc.xy_px[0], xy[:, 1] - disc.xy_px[1]) < disc.mask_radius_px
    return out


def body_discs_or_none(predictor, frame, site, prior, uncertainty_px: float = 0.0):
    """``predictor.discs(...)``, or () when the places cannot be computed (no prior, a time
    outside the tables)."""
    if prior is None:
        return ()
    try:
        return predictor.discs(frame.utc_jd1, frame.utc_jd2, site, prior, uncertainty_px)
    except ShipstarError:
        return ()
