"""Background and noise on a coarse mesh, from a sub-sampled view of the frame.

The frame is cut into square blocks (32 px by default); in each block only every
``step``-th pixel in each direction is read (64 samples a block), so the whole
estimate reads ~1/16 of the frame and copies nothing full-size. Per block: the median
is the background, a 3-sigma-clipped RMS about it the noise (it stays smooth for
integer data, where the MAD jumps in whole ADU). A 3x3 median filter over the block
grid then removes blocks biased by a bright star or a planet (as SExtractor does).
Values between block centres are bilinear.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

__all__ = ["Mesh", "estimate_mesh"]

#: Gaussian-consistent factor of a 3-sigma-clipped RMS (std of N(0,1) clipped at +-3).
_CLIPPED_RMS_TO_SIGMA = 1.0 / 0.9865


@dataclass(frozen=True)
class Mesh:
    """Background (``bg``) and noise (``noise``) per block, ADU, shape (n_by, n_bx).

    ``box_noise_factor``: RMS of a 3x3 sum of background pixels over ``3 * noise``; 1 for
    white noise, 2-3 for JPEG or demosaiced frames, whose noise is correlated.
    """

    bg: np.ndarray
    noise: np.ndarray
    block_px: int
    shape_hw: tuple
    box_noise_factor: float = 1.0

    def _weights(self, coord, n_blocks):
        g = (np.asarray(coord, dtype=float) - (self.block_px - 1) / 2.0) / self.block_px
        g = np.clip(g, 0.0, n_blocks - 1.0)
        i0 = np.minimum(np.floor(g).astype(np.intp), max(n_blocks - 2, 0))
        i1 = np.minimum(i0 + 1, n_blocks - 1)
        return i0, i1, g - i0

    def at(self, x_px, y_px):
        """Bilinear background and noise at pixel positions (arrays of equal shape)."""
        ny, nx = self.bg.shape
        x0, x1, fx = self._weights(x_px, nx)
        y0, y1, fy = self._weights(y_px, ny)
        out = []
        for grid in (self.bg, self.noise):
            top = grid[y0, x0] * (1 - fx) + grid[y0, x1] * fx
            bottom = grid[y1, x0] * (1 - fx) + grid[y1, x1] * fx
            out.append(top * (1 - fy) + bottom * fy)
        return out[0], out[1]

    @property
    def background_adu(self) -> float:
        return float(np.median(self.bg))

    @property
    def noise_adu(self) -> float:
        return float(np.median(self.noise))


def _block_samples(image, block_px, step):
    """(n_by, n_bx, k) float64 samples: every ``step``-th pixel of each block (last blocks padded)."""
    sub = image[step // 2::step, step // 2::step]
    b = block_px // step
    n_by = -(-sub.shape[0] // b)
    n_bx = -(-sub.shape[1] // b)
    pad = ((0, n_by * b - sub.shape[0]), (0, n_bx * b - sub.shape[1]))
    if pad[0][1] or pad[1][1]:
        sub = np.pad(sub, pad, mode="symmetric")
    blocks = sub.reshape(n_by, b, n_bx, b).swapaxes(1, 2).reshape(n_by, n_bx, b * b)
    # float64: a float32 copy overflows to inf above 3.4e38, and the squared deviations of
    # values above 1.8e19 overflow too (RuntimeWarnings, inf in the block statistics)
    return blocks.astype(np.float64)


def _sorted_median(samples):
    """Median along the last axis (a full sort of 64 values beats np.median's partition)."""
    ordered = np.sort(samples, axis=-1)
    k = ordered.shape[-1]
    return 0.5 * (ordered[..., (k - 1) // 2] + ordered[..., k // 2])


def estimate_mesh(image, *, block_px=32, quantum_adu=0.0) -> Mesh:
    """Background and noise mesh of a 2-D image.

    Parameters
    ----------
    image : (H, W) array
        The frame (any real dtype; not copied).
    block_px : int
        Block size; reduced for small frames so that there are at least 2x2 blocks.
    quantum_adu : float
        Step of the pixel values (1 for integer data, 0 for float): the noise is never
        below the quantisation noise ``quantum / sqrt(12)``.

    Returns
    -------
    Mesh
    """
    from scipy.ndimage import median_filter

    height, width = image.shape
    block_px = int(max(4, min(block_px, min(height, width) // 2)))
    step = max(1, block_px // 8)
    block_px = (block_px // step) * step
    samples = _block_samples(image, block_px, step)
    if quantum_adu == 0.0 and np.array_equal(samples, np.round(samples)):
        quantum_adu = 1.0                   # float frame holding integer counts
    med = _sorted_median(samples)
    dev = samples - med[:, :, None]
    mad_sigma = 1.4826 * _sorted_median(np.abs(dev))
    clip = 3.0 * np.maximum(mad_sigma, quantum_adu)[:, :, None]
    inside = np.abs(dev) <= clip
    rms = np.sqrt(np.sum(np.where(inside, dev * dev, 0.0), axis=2) / np.maximum(inside.sum(axis=2), 1))
    floor = max(quantum_adu / np.sqrt(12.0), 1e-9 * max(1.0, float(np.max(np.abs(med)))))
    noise = np.maximum(rms * _CLIPPED_RMS_TO_SIGMA, floor)
    if min(med.shape) >= 3:
        med = median_filter(med, size=3, mode="nearest")
        noise = np.maximum(noise, median_filter(noise, size=3, mode="nearest"))
    mesh = Mesh(bg=med.astype(float), noise=noise.astype(float), block_px=block_px, shape_hw=(height, width))
    return replace(mesh, box_noise_factor=_box_noise_factor(image, mesh))


def _box_noise_factor(image, mesh, max_samples=4096):
    """Robust RMS of 3x3 background sums at a regular grid of points, over 3 x pixel noise (>= 1)."""
    height, width = image.shape
    step = max(3, int(np.sqrt(height * width / max_samples)))
    rows, cols = np.meshgrid(np.arange(1, height - 1, step), np.arange(1, width - 1, step), indexing="ij")
    rows, cols = rows.ravel(), cols.ravel()
    if rows.size < 16:
        return 1.0
    total = np.zeros(rows.size)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            total += image[rows + dr, cols + dc]
    bg, noise = mesh.at(cols, rows)
    z = (total - 9.0 * bg) / (3.0 * noise)
    z -= np.median(z)
    return float(max(1.0, 1.4826 * np.median(np.abs(z))))
