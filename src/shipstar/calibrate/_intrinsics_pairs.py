"""Observation equations: interstar cosines, sines and angles, and per-star directions.

All frames are stacked (:class:`StarSet`) so that one evaluation handles every star of
every frame.  An evaluation gives the residual vector ``r`` (*reference minus measured*,
seed 002 eq. 8: ``R_ij = |v_i x v_j| - F_ij``) and ``A = dr / dtheta`` for the free
parameters (natural units), and keeps what is needed to form, frame by frame,
``G_f = dr_f / dxy_f`` (the centroids' influence, for the covariance).

Kinds:

``"cosine"``
    ``v_i . v_j - w_i . w_j`` (seed 002 eq. 3a);
``"sine"``
    ``|v_i x v_j| - |w_i x w_j|`` (seed 002 eq. 3b-6);
``"angle"``
    ``angle(v_i, v_j) - angle(w_i, w_j)`` (atan2 form, exact at every separation);
``"star"``
    per star, the two tangent-plane components (rad) of ``v_i - C_f w_i`` with ``C_f``
    the frame's attitude ``C_ref_from_sensor``.  ``A_att`` (2N, 3) holds the derivative by
    a small rotation ``C_f <- C_f exp([dphi x])`` about the sensor axes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from shipstar.calibrate._intrinsics_model import sensor_vectors

__all__ = ["StarSet", "PAIR_KINDS", "Evaluation", "evaluate", "tangent_basis"]

PAIR_KINDS = ("cosine", "sine", "angle")
#: pairs closer than this (rad) carry no usable angle information and are skipped
_MIN_PAIR_SIN = 1e-9


@dataclass(frozen=True, eq=False)
class StarSet:
    """The matched stars of all frames, stacked frame after frame.

    Attributes
    ----------
    xy_px : ndarray (N, 2)
    v_ref : ndarray (N, 3)
        Unit reference directions (apparent, refracted), each frame in any one frame of
        axes.
    starts, counts : ndarray (F,)
        First row and number of stars of each frame.
    pair_i, pair_j : ndarray (M,)
        Global star indices of the pairs ``i < j`` of each frame, frame after frame.
    pair_starts, pair_counts : ndarray (F,)
    """

    xy_px: np.ndarray
    v_ref: np.ndarray
    starts: np.ndarray
    counts: np.ndarray
    pair_i: np.ndarray
    pair_j: np.ndarray
    pair_starts: np.ndarray
    pair_counts: np.ndarray
    _ref: dict = field(default_factory=dict, repr=False)

    @classmethod
    def build(cls, frames) -> "StarSet":
        """From a sequence of ``(xy_px (n, 2), v_ref (n, 3))``."""
        xy = [np.asarray(f[0], float).reshape(-1, 2) for f in frames]
        v = [np.asarray(f[1], float).reshape(-1, 3) for f in frames]
        counts = np.array([len(a) for a in xy], dtype=np.intp)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.intp)
        vv = np.concatenate(v) if v else np.zeros((0, 3))
        vv = vv / np.linalg.norm(vv, axis=1, keepdims=True)
        pi, pj, pc = [], [], []
        for s, n in zip(starts, counts):
            i, j = np.triu_indices(n, k=1)
            i, j = i + s, j + s
            keep = np.linalg.norm(np.cross(vv[i], vv[j]), axis=1) > _MIN_PAIR_SIN
            pi.append(i[keep])
            pj.append(j[keep])
            pc.append(int(keep.sum()))
        pair_counts = np.array(pc, dtype=np.intp)
        pair_starts = np.concatenate([[0], np.cumsum(pair_counts)[:-1]]).astype(np.intp)
        cat = (lambda parts: np.concatenate(parts).astype(np.intp)) if pi else (
            lambda parts: np.zeros(0, np.intp))
        return cls(np.concatenate(xy) if xy else np.zeros((0, 2)), vv, starts, counts,
                   cat(pi), cat(pj), pair_starts, pair_counts)

    @property
    def n_frames(self) -> int:
        return len(self.counts)

    @property
    def n_stars(self) -> int:
        return len(self.xy_px)

    @property
    def n_pairs(self) -> int:
        return len(self.pair_i)

    @property
    def star_frame(self) -> np.ndarray:
        return np.repeat(np.arange(self.n_frames), self.counts)

    def frame(self, f: int):
        """``(xy_px, v_ref)`` of frame ``f``."""
        s, n = self.starts[f], self.counts[f]
        return self.xy_px[s:s + n], self.v_ref[s:s + n]

    def subset(self, mask) -> "StarSet":
        """The stars in ``mask`` (N,) bool; frames left with < 3 stars are dropped."""
        mask = np.asarray(mask, bool)
        frames = []
        for f in range(self.n_frames):
            s, n = self.starts[f], self.counts[f]
            m = mask[s:s + n]
            if m.sum() >= 3:
                frames.append((self.xy_px[s:s + n][m], self.v_ref[s:s + n][m]))
        return StarSet.build(frames)

    def ref_values(self, kind: str) -> np.ndarray:
        if kind not in self._ref:
            a, b = self.v_ref[self.pair_i], self.v_ref[self.pair_j]
            c = np.einsum("ni,ni->n", a, b)
            s = np.linalg.norm(np.cross(a, b), axis=1)
            self._ref.update(cosine=c, sine=s, angle=np.arctan2(s, c))
        return self._ref[kind]


def tangent_basis(v):
    """Two unit vectors ``(n, 2, 3)`` orthogonal to each unit vector ``v`` (n, 3) and to
    each other."""
    v = np.asarray(v, float)
    helper = np.where((np.abs(v[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    a = np.cross(v, helper)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(v, a)
    return np.stack([a, b], axis=1)


def _cross_norm(a, b):
    c0 = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    c1 = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    c2 = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)


@dataclass
class Evaluation:
    """Residuals and derivatives of one kind of equations at one parameter point.

    ``r`` (R,) and ``A`` (R, P) are stacked over frames; ``row_starts``/``row_counts``
    give each frame's rows.  ``frame_G(f)`` builds ``dr_f / dxy_f`` (R_f, 2 n_f).
    For ``"star"`` also ``A_att`` (R, 3).
    """

    kind: str
    r: np.ndarray
    A: np.ndarray
    row_starts: np.ndarray
    row_counts: np.ndarray
    stars: StarSet
    g_parts: tuple
    A_att: np.ndarray | None = None

    def frame_rows(self, f: int) -> slice:
        return slice(self.row_starts[f], self.row_starts[f] + self.row_counts[f])

    def frame_G(self, f: int) -> np.ndarray:
        st = self.stars
        n = st.counts[f]
        if self.kind == "star":
            g = self.g_parts[0][st.starts[f]:st.starts[f] + n]          # (n, 2, 2)
            G = np.zeros((2 * n, 2 * n))
            idx = np.arange(n) * 2
            for k in range(2):
                for m in range(2):
                    G[idx + k, idx + m] = g[:, k, m]
            return G
        g_i, g_j = self.g_parts
        rows = self.frame_rows(f)
        i = st.pair_i[rows] - st.starts[f]
        j = st.pair_j[rows] - st.starts[f]
        m = len(i)
        G = np.zeros((m, 2 * n))
        rr = np.arange(m)
        for k in range(2):
            G[rr, 2 * i + k] = g_i[rows, k]
            G[rr, 2 * j + k] = g_j[rows, k]
        return G


def evaluate(stars: StarSet, full, pixel_mm: float, free, kind: str,
             attitudes=None, bases=None) -> Evaluation:
    """Evaluate the ``kind`` equations for all frames (``attitudes`` (F, 3, 3) and the
    stars' tangent ``bases`` (N, 2, 3) for ``"star"``)."""
    w, dw, dxy = sensor_vectors(stars.xy_px, full, pixel_mm, free, want_xy=True)
    if kind == "star":
        return _evaluate_star(stars, w, dw, dxy, attitudes, bases)
    i, j = stars.pair_i, stars.pair_j
    wi, wj = w[i], w[j]
    c = np.einsum("ni,ni->n", wi, wj)
    s = _cross_norm(wi, wj)
    dc_dtheta = np.einsum("ni,nip->np", wj, dw[i]) + np.einsum("ni,nip->np", wi, dw[j])
    if kind == "cosine":
        meas, factor = c, np.ones_like(c)
    elif kind == "sine":
        meas, factor = s, -c / s
    elif kind == "angle":
        meas, factor = np.arctan2(s, c), -1.0 / s
    else:                                                   # pragma: no cover - internal
        raise ValueError(kind)
    r = stars.ref_values(kind) - meas
    A = -factor[:, None] * dc_dtheta
    g_i = -factor[:, None] * np.einsum("ni,nik->nk", wj, dxy[i])
    g_j = -factor[:, None] * np.einsum("ni,nik->nk", wi, dxy[j])
    return Evaluation(kind, r, A, stars.pair_starts, stars.pair_counts, stars, (g_i, g_j))


def _evaluate_star(stars, w, dw, dxy, attitudes, bases) -> Evaluation:
    n = stars.n_stars
    C = np.asarray(attitudes, float)[stars.star_frame]                # (N, 3, 3)
    TC = np.einsum("nki,nij->nkj", bases, C)                          # rows a^T C
    r = -np.einsum("nki,ni->nk", TC, w).reshape(2 * n)                # a^T (v - C w), a ⟂ v
    A = -np.einsum("nki,nip->nkp", TC, dw).reshape(2 * n, -1)
    # C w -> C (w + dphi x w) = C w - C [w]x dphi  =>  dr = a^T C [w]x dphi
    wx = np.zeros((n, 3, 3))
    wx[:, 0, 1], wx[:, 0, 2] = -w[:, 2], w[:, 1]
    wx[:, 1, 0], wx[:, 1, 2] = w[:, 2], -w[:, 0]
    wx[:, 2, 0], wx[:, 2, 1] = -w[:, 1], w[:, 0]
    A_att = np.einsum("nki,nij->nkj", TC, wx).reshape(2 * n, 3)
    g = -np.einsum("nki,nij->nkj", TC, dxy)                           # (N, 2, 2)
    return Evaluation("star", r, A, 2 * stars.starts, 2 * stars.counts, stars, (g,), A_att)
