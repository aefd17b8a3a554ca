"""Which distortion terms do the data support?  Forward selection by likelihood ratio.

Starting from the pinhole model (f, principal point), each round fits every candidate
model with one more Weng term (the joint fit on per-star directions, with per-frame
attitudes, so the residuals are independent and the cost drop is a chi-square) and adds
the term with the largest drop if that drop exceeds :data:`SUPPORT_CHI2`.  The noise
scale is taken from the fit with every term, so a missing term never inflates it.

A likelihood ratio (refitting) rather than a Wald test on one fit, because the Weng
model is strongly nonlinear along the principal point / decentring valley: a local
covariance can call a term significant that another point of the valley does without.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shipstar.calibrate._intrinsics_model import TERM_FIELDS, TERMS
from shipstar.calibrate._intrinsics_solve import joint

__all__ = ["TermSelection", "select_terms", "SUPPORT_CHI2"]

#: Chi-square drop a term must bring to count as supported: the 0.1 % tail of a
#: chi-square with one degree of freedom (3.3 sigma).
SUPPORT_CHI2 = 10.83


@dataclass(frozen=True)
class TermSelection:
    """Outcome of :func:`select_terms`.

    Attributes
    ----------
    supported : tuple of str
        Short names (``"k1"``, ...) of the supported terms, in the order they were added.
    delta_chi2 : dict
        For every term, the chi-square drop it brought when it was last tried (added
        terms: when added; the others: in the final round).
    """

    supported: tuple
    delta_chi2: dict


def _cost(stars, start, terms, robust, k) -> float:
    """Huber cost (threshold ``k``, the full model's) of the best fit with ``terms``."""
    out = joint(stars, start, [TERM_FIELDS[t] for t in terms], attitudes=True, robust=robust)
    a = np.abs(out.fit.lin.ev.r)
    if not np.isfinite(k):
        return float(a @ a)
    return float(np.sum(np.where(a <= k, a * a, 2.0 * k * a - k * k)))


def select_terms(stars, start, *, candidates=TERMS, robust: bool = True) -> TermSelection:
    """Forward selection of Weng terms on the star set, starting from camera ``start``."""
    candidates = tuple(candidates)
    full = joint(stars, start, [TERM_FIELDS[t] for t in candidates], attitudes=True, robust=robust)
    n_rows = 2 * stars.n_stars
    dof = n_rows - 3 * stars.n_frames - 3 - len(candidates)
    sigma2 = full.fit.cost / max(dof, 1)
    k = full.fit.huber_threshold
    chosen: list[str] = []
    drops: dict[str, float] = {}
    current = _cost(stars, start, chosen, robust, k)
    remaining = list(candidates)
    while remaining:
        trial = {t: _cost(stars, start, chosen + [t], robust, k) for t in remaining}
        for t, c in trial.items():
            drops[t] = max(0.0, (current - c) / sigma2)
        best = max(remaining, key=lambda t: drops[t])
        if drops[best] < SUPPORT_CHI2:
            break
        chosen.append(best)
        remaining.remove(best)
        current = trial[best]
    order = {t: i for i, t in enumerate(TERMS)}
    return TermSelection(tuple(sorted(chosen, key=order.get)),
                         {t: float(drops.get(t, np.nan)) for t in candidates})
