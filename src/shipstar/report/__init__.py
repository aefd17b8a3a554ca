"""HTML reports: one self-contained file, plots embedded as base64 PNG.

Public API::

    Report(title, subtitle="")                    # builder: section, paragraph, table, figure, write
    plot_frame_stars(image, detected_xy_px=, identified_xy_px=, identified_hip=) -> PNG bytes
    plot_sky_chart(tracks_deg=, footprints_deg=, stars_az_el_deg=, stars_mag=, heading_deg=) -> PNG bytes
    plot_installation_histograms(errors_arcsec, seed_std_arcsec=) -> PNG bytes
    plot_attitude_errors(series, shade_s=) -> PNG bytes
    plot_layout_sweep(x_deg, predicted, measured=) -> PNG bytes
    session_report(result, path, truth=None, ins=None, title=...) -> Path   # a pipeline SessionResult
    plot_ins_errors(t_s, error_arcsec, error_sigma_arcsec, bridged, true_error_arcsec=) -> PNG bytes
    plot_ins_outage(t_s, sigma_arcsec, bridged, error_arcsec=) -> PNG bytes
    ins_report(ins_solution, path, truth=None, true_terms=None) -> Path   # measure --ins-report

matplotlib is imported only when a plot is made (``import shipstar.report`` stays cheap).
"""

from __future__ import annotations

from shipstar.report._frame_plot import plot_frame_stars
from shipstar.report._html import VERDICT_ID, Report
from shipstar.report._ins_plot import ins_report, plot_ins_errors, plot_ins_outage
from shipstar.report._install_plot import plot_installation_histograms
from shipstar.report._layout_plot import plot_layout_sweep
from shipstar.report._series_plot import plot_attitude_errors
from shipstar.report._session import session_report
from shipstar.report._sky_plot import plot_sky_chart

__all__ = ["Report", "VERDICT_ID", "plot_frame_stars", "plot_sky_chart", "plot_installation_histograms",
           "plot_attitude_errors", "plot_layout_sweep", "session_report", "plot_ins_errors", "plot_ins_outage",
           "ins_report"]
