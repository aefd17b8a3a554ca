"""Matplotlib figures without pyplot (no global state, no display): Agg canvas -> PNG bytes."""

from __future__ import annotations

import io

__all__ = ["new_figure", "png_bytes", "METHOD_COLORS", "color_for"]

#: Stable colours per method / sensor name across every plot of a report.
METHOD_COLORS = {"single A1": "#1f77b4", "single A2": "#ff7f0e", "seed rule": "#2ca02c", "joint": "#d62728",
                 "A1": "#1f77b4", "A2": "#ff7f0e"}
_CYCLE = ("#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf")


def color_for(name: str, k: int = 0) -> str:
    """The colour of a method or sensor name (a cycle colour for other names)."""
    return METHOD_COLORS.get(name, _CYCLE[k % len(_CYCLE)])


def new_figure(width_in: float, height_in: float, nrows: int = 1, ncols: int = 1, **subplot_kw):
    """``(figure, axes array (nrows, ncols))`` on an Agg canvas, constrained layout."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False, subplot_kw=subplot_kw or None)
    return fig, axes


def png_bytes(fig, dpi: int = 100) -> bytes:
    """The figure as PNG bytes."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()
