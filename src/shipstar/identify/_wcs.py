"""World coordinate system (FITS WCS, TAN with SIP distortion) of a solved image.

The solution maps a pixel to a sensor-frame direction (the camera model, or the pinhole
with the solved focal scale and radial term ``k1``) and the sensor frame to ICRS
(``C_icrs_from_sensor``).  A FITS TAN projection at the principal point (``CRPIX``,
``CRVAL`` = the direction of that pixel) with a linear ``CD`` matrix reproduces a
distortion-free camera exactly; a camera with distortion (fitted radial ``k1``, or a
calibrated camera's Weng terms) gets SIP polynomials (Shupe et al. 2005):

    (xi, eta) = CD @ (u + A(u, v), v + B(u, v)),   (u, v) = pixel - CRPIX

``A``, ``B`` of orders 2 .. ``sip_order``, least-squares fitted with ``CD`` on a grid
over the image (exact for the pinhole's ``k1``: a pure third-order term).
Pixel indices: shipstar's are 0-based (top-left pixel centre (0, 0), y down); FITS'
are 1-based, so ``CRPIX = principal point + 1``.  The image's row order is kept: a
viewer that shows FITS row 1 at the bottom shows the image upside down, and the WCS
follows it.
"""

from __future__ import annotations

import math

import numpy as np

from shipstar.units import RAD2DEG

__all__ = ["sensor_from_pixels", "wcs_cards", "write_wcs", "principal_point_px"]

#: grid points per image axis used to fit SIP
_GRID = 24


def principal_point_px(result) -> tuple[float, float]:
    """``(x0_px, y0_px)`` (0-based) of a solution's camera model."""
    cam = result.camera
    if cam is not None:
        return float(cam.x0_px), float(cam.y0_px)
    h, w = result.image_shape_hw
    return (w - 1) / 2.0, (h - 1) / 2.0


def sensor_from_pixels(result, xy_px) -> np.ndarray:
    """Sensor-frame unit vectors ``(N, 3)`` of pixel positions ``(N, 2)`` in a solution's
    camera model (the calibrated camera, or the pinhole with the solved scale and k1)."""
    xy = np.asarray(xy_px, dtype=float).reshape(-1, 2)
    if result.camera is not None:
        return result.camera.unproject(xy)
    x0, y0 = principal_point_px(result)
    f = result.focal_px_nominal
    ident = result.identification
    t0 = np.stack([-(xy[:, 1] - y0) / f, (xy[:, 0] - x0) / f], axis=1)
    t = t0 * (ident.focal_scale * (1.0 + ident.radial_k1 * np.einsum("ij,ij->i", t0, t0)))[:, None]
    u = np.empty((xy.shape[0], 3))
    u[:, 0] = 1.0
    u[:, 1:] = t
    return u / np.linalg.norm(u, axis=1)[:, None]


def _has_distortion(result) -> bool:
    if result.camera is not None:
        return not result.camera.distortion.is_zero
    return result.identification.radial_k1 != 0.0


def _sip_terms(order: int):
    return [(p, q) for n in range(2, order + 1) for p in range(n, -1, -1) for q in (n - p,)]


def wcs_cards(result, sip_order: int = 4) -> list[tuple[str, object, str]]:
    """FITS header cards ``(key, value, comment)`` of a solved image's WCS.

    TAN (``RA---TAN``/``DEC--TAN``) without distortion, ``-SIP`` with ``A_p_q``/``B_p_q``
    of order ``sip_order`` (3 for the pinhole's radial term) where the camera has
    distortion.  Raises ValueError for an unsolved result.
    """
    if not result.solved:
        raise ValueError("no WCS: the image is not solved")
    C = np.asarray(result.C_icrs_from_sensor, dtype=float)
    x0, y0 = principal_point_px(result)
    h, w = result.image_shape_hw
    gx, gy = np.meshgrid(np.linspace(-0.5, w - 0.5, _GRID), np.linspace(-0.5, h - 0.5, _GRID))
    grid = np.stack([gx.ravel(), gy.ravel()], axis=1)
    centre = sensor_from_pixels(result, [[x0, y0]])[0]
    b = C @ centre                                   # CRVAL direction
    ra = math.atan2(b[1], b[0]) % (2.0 * math.pi)
    dec = math.asin(max(-1.0, min(1.0, b[2])))
    east = np.array([-math.sin(ra), math.cos(ra), 0.0])
    north = np.cross(b, east)
    v = sensor_from_pixels(result, grid) @ C.T
    vb = v @ b
    xi, eta = (v @ east) / vb * RAD2DEG, (v @ north) / vb * RAD2DEG
    d = grid - [x0, y0]
    sip = _has_distortion(result)
    order = (3 if result.camera is None else int(sip_order)) if sip else 1
    terms = _sip_terms(order) if sip else []
    design = np.column_stack([d[:, 0], d[:, 1]] + [d[:, 0] ** p * d[:, 1] ** q for p, q in terms])
    coef, *_ = np.linalg.lstsq(design, np.stack([xi, eta], axis=1), rcond=None)
    cd = coef[:2].T                                  # (2, 2): rows xi, eta; columns u, v
    cards = [("WCSAXES", 2, "two world axes"),
             ("CTYPE1", "RA---TAN-SIP" if sip else "RA---TAN", "gnomonic" + (" + SIP" if sip else "")),
             ("CTYPE2", "DEC--TAN-SIP" if sip else "DEC--TAN", "gnomonic" + (" + SIP" if sip else "")),
             ("CUNIT1", "deg", ""), ("CUNIT2", "deg", ""),
             ("RADESYS", "ICRS", "shipstar: Hipparcos (ICRS) at the solve epoch"),
             ("CRPIX1", x0 + 1.0, "principal point x (1-based)"),
             ("CRPIX2", y0 + 1.0, "principal point y (1-based)"),
             ("CRVAL1", ra * RAD2DEG, "RA of CRPIX (deg)"),
             ("CRVAL2", dec * RAD2DEG, "Dec of CRPIX (deg)"),
             ("CD1_1", float(cd[0, 0]), ""), ("CD1_2", float(cd[0, 1]), ""),
             ("CD2_1", float(cd[1, 0]), ""), ("CD2_2", float(cd[1, 1]), "")]
    if sip:
        sipc = np.linalg.solve(cd, coef[2:].T)       # (2, T): pixel-space A, B
        cards += [("A_ORDER", order, "SIP order"), ("B_ORDER", order, "SIP order")]
        cards += [(f"A_{p}_{q}", float(c), "") for (p, q), c in zip(terms, sipc[0])]
        cards += [(f"B_{p}_{q}", float(c), "") for (p, q), c in zip(terms, sipc[1])]
    return cards


def write_wcs(result, path, image=None, sip_order: int = 4) -> None:
    """Write the WCS of a solved image to ``path``: a FITS file with the pixels
    (``image``: the source file's path - a FITS file is copied with its header - or
    pixels) or, with ``image=None``, a sidecar text header (one 80-character card a line,
    ``astropy.io.fits.Header.fromtextfile`` reads it).  astropy writes the file
    (imported here only)."""
    from astropy.io import fits

    from shipstar._atomic import atomic_path

    hdr = None
    data = None
    if image is not None:
        if isinstance(image, np.ndarray):
            data = image
        else:
            from shipstar.extract import read_image

            name = str(image)
            data = np.asarray(read_image(name))          # top row first (ROWORDER applied)
            with open(name, "rb") as fh:
                head = fh.read(9)
            if head == b"SIMPLE  =" or head.startswith(b"\x1f\x8b"):
                hdr = fits.getheader(name, 0)
                for key in ("BZERO", "BSCALE", "BLANK", "EXTEND"):
                    hdr.remove(key, ignore_missing=True)
                hdr["ROWORDER"] = ("TOP-DOWN", "first row stored is the top (shipstar)")
        if data.dtype.kind == "f":
            data = data.astype(np.float32)
        elif data.dtype.kind in "ui" and data.dtype.itemsize > 2:
            data = data.astype(np.float32)
    hdu = fits.PrimaryHDU(data=data, header=hdr)
    for key in list(hdu.header.keys()):
        if key.startswith(("A_", "B_", "AP_", "BP_")) or key in (
                "CTYPE1", "CTYPE2", "CRPIX1", "CRPIX2", "CRVAL1", "CRVAL2", "CD1_1", "CD1_2",
                "CD2_1", "CD2_2", "CDELT1", "CDELT2", "PC1_1", "PC1_2", "PC2_1", "PC2_2",
                "CROTA2", "WCSAXES", "CUNIT1", "CUNIT2", "RADESYS", "EQUINOX"):
            del hdu.header[key]
    for key, value, comment in wcs_cards(result, sip_order):
        hdu.header[key] = (value, comment)
    q = result.q_icrs_from_sensor_wxyz
    for k, name in enumerate("WXYZ"):
        hdu.header[f"SSQ{name}"] = (float(q[k]), f"shipstar q_icrs_from_sensor_wxyz[{k}]")
    hdu.header["SSPFALSE"] = (float(result.identification.p_false), "shipstar false-match probability")
    hdu.header["SSMATCH"] = (int(result.matched), "shipstar matched stars")
    h, w = result.image_shape_hw
    with atomic_path(path) as tmp:
        if image is None:
            hdr = fits.Header()
            hdr["IMAGEW"] = (int(w), "image width (px)")
            hdr["IMAGEH"] = (int(h), "image height (px)")
            for card in hdu.header.cards:
                if card.keyword not in ("SIMPLE", "BITPIX", "NAXIS", "EXTEND"):
                    hdr.append(card)
            hdr.totextfile(tmp, overwrite=True)
        else:
            hdu.writeto(tmp, overwrite=True)
