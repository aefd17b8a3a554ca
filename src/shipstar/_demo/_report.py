"""The demo's HTML report: results table, frames, sky chart, installation histograms,
errors against time and the error model of the installed layout."""

from __future__ import annotations

import math

import numpy as np

from shipstar.units import RAD2DEG

__all__ = ["write_demo_report"]

_ANG = ("az", "el", "roll")
_SHIP = ("heading", "pitch", "roll")


def _f(x, nd: int = 2) -> str:
    if x is None or not math.isfinite(float(x)):
        return "-"
    x = float(x)
    return f"{0.0 if abs(x) < 0.5 * 10 ** -nd else x:.{nd}f}"                 # no "-0.00"


def _frame_figure(d, database, options) -> bytes:
    """The sample dock frame of a sensor with its extracted and identified stars."""
    from shipstar.extract import extract_stars
    from shipstar.identify import identify_lost_in_space
    from shipstar.report import plot_frame_stars

    cam = d.sample.simulated.camera
    image = d.sample.simulated.image
    ex = extract_stars(image, threshold_sigma=options.threshold_sigma, psf_sigma_px=cam.psf_sigma_px,
                       gain_e_per_adu=cam.gain_e_per_adu)
    idn = identify_lost_in_space(ex.xy_px, database, camera=cam, centroid_error_px=options.identify_error_px)
    ok = np.asarray(idn.hip) >= 0
    r = d.sample_result
    used, rms = (r.n_used, r.rms_arcsec) if r is not None else (0, math.nan)
    title = (f"{d.name}, dock frame {d.sample.frame.label} ({d.sample.simulated.utc_iso[:19]} UTC)\n"
             f"{len(ex.xy_px)} detected, {int(ok.sum())} identified (lost in space); the pipeline used "
             f"{used}, residual RMS {_f(rms)}\u2033")
    return plot_frame_stars(image, detected_xy_px=ex.xy_px, identified_xy_px=ex.xy_px[ok],
                            identified_hip=np.asarray(idn.hip)[ok], title=title)


def _footprint_deg(camera, C_hor_from_sensor) -> np.ndarray:
    """The image border as (az, el) in degrees, (K, 2)."""
    from shipstar.frames import az_el_from_unit

    w, h = camera.width_px - 1.0, camera.height_px - 1.0
    s = np.linspace(0.0, 1.0, 9)[:-1]
    border = np.concatenate([np.stack([s * w, 0 * s], -1), np.stack([w + 0 * s, s * h], -1),
                             np.stack([(1 - s) * w, h + 0 * s], -1), np.stack([0 * s, (1 - s) * h], -1)])
    az, el = az_el_from_unit(camera.unproject(border) @ np.asarray(C_hor_from_sensor).T)
    return np.stack([az, el], -1) * RAD2DEG


def _sky_figure(spec, sea) -> bytes:
    from shipstar.frames import az_el_from_unit
    from shipstar.report import plot_sky_chart
    from shipstar.sky.apparent import frame_context
    from shipstar.sky.catalog import navigation_catalog

    cat = navigation_catalog(4.5)
    t_mid = 0.5 * spec.duration_s
    ctx = frame_context(*spec.utc_jd(t_mid), spec.site(t_mid))
    az, el = az_el_from_unit(ctx.hor_from_catalog(cat))
    C_hd = spec.motion.C_hor_from_deck(t_mid)
    foot = {s.name: _footprint_deg(s.camera, C_hd @ s.C_deck_from_sensor) for s in spec.sensors}
    heading = float(spec.motion.angles_rad(t_mid)[0]) * RAD2DEG
    return plot_sky_chart(tracks_deg=sea.sensor_tracks_deg, footprints_deg=foot,
                          stars_az_el_deg=np.stack([az, el], -1) * RAD2DEG, stars_mag=cat.mag, heading_deg=heading,
                          title=f"Sky at sea, {spec.utc_iso(t_mid)[:19]} UTC (plan view: zenith at the centre, "
                                "north up, east right)")


def _dock_table(rep, result) -> None:
    from shipstar._demo._table import SEED_INSTALL_STD_ARCSEC

    rows, classes = [], []
    for d in result.dock:
        inst, seed = d.installation, SEED_INSTALL_STD_ARCSEC.get(d.name)
        for k, a in enumerate(_ANG):
            rows.append([d.name, a, f"{d.true_deg[k]:.5f}", f"{d.estimated_deg[k]:.5f}", _f(d.bias_arcsec[k]),
                         _f(inst.std_arcsec[k]), _f(inst.sem_arcsec[k]), _f(seed[k]) if seed else "-"])
            classes.append("")
    rep.table(["sensor", "angle", "true (deg)", "calibrated (deg)", "bias (\u2033)", "std per frame (\u2033)",
               "std of mean (\u2033)", "seed 000 std (\u2033)"], rows, left_columns=2, row_classes=classes)


def _sea_table(rep, result) -> None:
    from shipstar._demo._table import seed_rms_arcsec

    head = ["method", *_SHIP * 3, "solved"]
    rows = []
    for m in result.sea.methods:
        seed = seed_rms_arcsec(m.name) or (None,) * 3
        rows.append([m.name, *(_f(v) for v in m.rms_arcsec("image")), *(_f(v) for v in m.rms_arcsec("centroid")),
                     *(_f(v) if v is not None else "-" for v in seed), f"{m.n_solved}/{len(m.t_s)}"])
    sea = result.sea.sensors[0]
    rep.table(head, rows, groups=[("", 1), (f"RMS error (\u2033), image level ({sea.n_image_level} frames)", 3),
                                  (f"centroid level ({sea.n_frames - sea.n_image_level} frames)", 3),
                                  ("seeds (real ships)", 3), ("", 1)])


def _intro(rep, result) -> None:
    dock, sea = result.dock, result.sea
    rep.paragraph(
        f"Dock: {result.dock_config.label}; {dock[0].n_frames} frames per sensor at "
        f"{result.dock_config.frame_rate_hz:g} frames/s, {dock[0].n_image_level} rendered as raw images "
        "(image level: PSF, photon and read noise, hot pixels, 12-bit ADC), then extracted, identified "
        "(lost in space, then tracking), solved in the horizontal frame with per-star refraction, and "
        "averaged into installation angles (seed 000 eq. 17).")
    rep.paragraph(
        f"Sea: {result.sea_config.label}; {sea.sensors[0].n_frames} frames per sensor, the first "
        f"{sea.sensors[0].n_image_level} at image level (with motion smear), the rest at centroid level "
        f"(catalog stars to Hp {result.sea_spec.mag_limit:g} with {result.sea_spec.centroid_sigma_px:g} px "
        "Gaussian centroid noise; identification still runs). The ship attitude uses the installations "
        "calibrated in dock, not the true ones.")
    rep.paragraph("The seeds' figures come from real sessions (theodolite heading, deck flexure, clock offsets, "
                  "real optics and weather). The simulation has none of those error sources, so its numbers "
                  "show what the algorithms reach on ideal data, not what a real ship will give.", note=True)


def _series_figure(result) -> bytes:
    from shipstar.report import plot_attitude_errors

    sea = result.sea
    series = [(m.name, m.t_s, m.errors_arcsec) for m in sea.methods]
    img = np.concatenate([m.t_s[m.image_level] for m in sea.methods])
    shade = (float(img.min()) - 0.05, float(img.max()) + 0.05) if img.size else None
    cen = np.concatenate([np.abs(m.errors_arcsec[~m.image_level]).ravel() for m in sea.methods])
    cen = cen[np.isfinite(cen)]
    lin = 1.2 * float(cen.max()) if cen.size and cen.max() > 0 else None
    return plot_attitude_errors(series, shade_s=shade, shade_label="image-level frames", linear_limit_arcsec=lin)


def _install_figure(result) -> bytes:
    from shipstar._demo._table import SEED_INSTALL_STD_ARCSEC
    from shipstar.report import plot_installation_histograms

    errors = {d.name: d.deviations_arcsec + d.bias_arcsec for d in result.dock}
    return plot_installation_histograms(errors, seed_std_arcsec={k: v for k, v in SEED_INSTALL_STD_ARCSEC.items()
                                                                 if k in errors})


def _layout_figure(result) -> bytes:
    from shipstar.report import plot_layout_sweep

    lay = result.layout
    return plot_layout_sweep(lay.roll_deg, lay.predicted, measured=lay.measured, xlabel="ship roll (deg), pitch 0",
                             title="Error model of the installed layout (lines) and the session's RMS by roll "
                                   "(markers)")


def _files(rep, result) -> None:
    rep.bullets([f"{k}: {v}" for k, v in result.files.items()])
    rep.paragraph("Run it again: shipstar demo" + (" --quick" if result.quick else "")
                  + f" --out {result.out_dir}.  Edit the configuration for your own ship: "
                    "shipstar demo --write-config my-ship, then shipstar demo --config my-ship.")


def write_demo_report(result, databases, path):
    """Write the demo's HTML report; returns its path."""
    from shipstar import __version__
    from shipstar.report import Report

    mode = "quick run" if result.quick else "full run"
    rep = Report("shipstar demo: dock calibration and ship attitude at sea",
                 subtitle=f"shipstar {__version__}, {mode}, {sum(result.timing_s.values()):.0f} s; "
                          "simulated frames of the seeds' sensors A1 and A2")
    rep.section("Results against truth and the seeds")
    _intro(rep, result)
    rep.heading("Installation calibration in dock")
    _dock_table(rep, result)
    rep.heading("Ship attitude at sea")
    _sea_table(rep, result)
    sea = result.sea
    rep.paragraph(f"Seed rule (seed 003): heading averaged, pitch from the fore-aft sensor ({sea.fore_aft_sensor}), "
                  f"roll from the athwartship sensor ({sea.athwartship_sensor}). Joint: one weighted attitude "
                  "solution of all stars of both sensors.")
    rep.section("Frames")
    options = result.dock_config.pipeline_options()
    if all(d.sample is None for d in result.dock):
        rep.paragraph("No dock frame was rendered as an image ([simulation] image_level_s = 0).")
    for d in result.dock:
        if d.sample is not None:
            rep.figure(_frame_figure(d, databases[d.name], options),
                       f"Sensor {d.name}: a raw dock frame (asinh stretch) with the extracted stars (squares) and "
                       "the identified ones (circles, HIP numbers).", f"frame {d.name}")
    rep.section("Where the sensors look")
    rep.figure(_sky_figure(result.sea_spec, result.sea),
               "Each sensor's boresight over the sea session (lines) and its field at mid-session (shaded), over "
               "the stars brighter than Hp 4.5.", "sky chart")
    rep.section("Installation angles")
    rep.figure(_install_figure(result), "Per-frame installation angles minus the truth, dock session. The roll "
               "about the boresight is the weak angle, as in seed 000.", "installation histograms")
    rep.section("Ship attitude errors against time")
    rep.figure(_series_figure(result), "Heading, pitch and roll error of each method at sea; the shaded span is "
               "the image-level part of the session.", "attitude errors")
    rep.section("Error model of the installed layout")
    rep.figure(_layout_figure(result), "shipstar.errormodel with each sensor's measured star count and star noise "
               "and the dock calibration's standard error as installation error, against the ship's roll.",
               "error model sweep")
    lay = result.layout
    rows = [[n, _f(a.n_stars, 1), _f(a.sigma_star_arcsec), _f(a.sigma_cross_arcsec), _f(a.sigma_roll_arcsec),
             ", ".join(_f(x) for x in lay.install_errors_arcsec[n])] for n, a in lay.accuracy.items()]
    rep.table(["sensor", "stars used", "star noise (\u2033)", "cross-boresight \u03c3 (\u2033)", "roll \u03c3 (\u2033)",
               "installation error az, el, roll (\u2033)"], rows)
    rep.section("Files and commands")
    _files(rep, result)
    return rep.write(path)
