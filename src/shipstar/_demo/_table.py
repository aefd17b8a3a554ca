"""The demo's results against truth, beside the seeds' published figures: text table and JSON."""

from __future__ import annotations

import math

__all__ = ["SEED_INSTALL_STD_ARCSEC", "SEED_SINGLE_RMS_ARCSEC", "SEED_FUSED_RMS_ARCSEC",
           "results_dict", "results_text", "seed_rms_arcsec"]

#: Seed 000 Tables 2-3: per-frame std of the calibrated installation (az, el, roll), arcsec
#: (the angles themselves are the demo's truth: shipstar.simulate._session.SEED_A1_INSTALL_DEG).
SEED_INSTALL_STD_ARCSEC = {"A1": (9.18, 5.89, 63.55), "A2": (6.06, 3.10, 54.62)}
#: Seed 000: single-sensor ship attitude RMS (heading, pitch, roll), arcsec, per-star refraction.
SEED_SINGLE_RMS_ARCSEC = {"A1": (45.62, 5.98, 67.37), "A2": (50.38, 74.12, 4.42)}
#: Seed 003: dual-sensor fused ship attitude RMS (heading, pitch, roll), arcsec.
SEED_FUSED_RMS_ARCSEC = (8.47, 7.16, 5.12)

_ANGLES = ("az", "el", "roll")
_SHIP = ("heading", "pitch", "roll")


def seed_rms_arcsec(method: str):
    """The seeds' RMS for a method name (``"single A1"``, ``"seed rule"``), or None."""
    if method == "seed rule":
        return SEED_FUSED_RMS_ARCSEC
    if method.startswith("single "):
        return SEED_SINGLE_RMS_ARCSEC.get(method[len("single "):])
    return None


def _num(x, nd: int = 3):
    x = float(x)
    return round(x, nd) if math.isfinite(x) else None


def _triple(keys, values, nd: int = 3):
    return None if values is None else {k: _num(v, nd) for k, v in zip(keys, values)}


def _dock_dict(dock, dock_cfg) -> dict:
    sensors = {}
    for d in dock:
        i = d.installation
        sensors[d.name] = {
            "true_deg": _triple(_ANGLES, d.true_deg, 7), "estimated_deg": _triple(_ANGLES, d.estimated_deg, 7),
            "bias_arcsec": _triple(_ANGLES, d.bias_arcsec), "std_arcsec": _triple(_ANGLES, i.std_arcsec),
            "sem_arcsec": _triple(_ANGLES, i.sem_arcsec),
            "seed_std_arcsec": _triple(_ANGLES, SEED_INSTALL_STD_ARCSEC.get(d.name)),
            "n_frames": d.n_frames, "n_image_level": d.n_image_level, "n_solved": d.n_solved, "n_used": i.n_used,
            "median_stars_used": _num(d.median_stars_used, 1),
            "median_residual_rms_arcsec": _num(d.median_residual_arcsec)}
    return {"label": dock_cfg.label, "start_utc": dock_cfg.start_utc, "sensors": sensors}


def _sea_dict(sea, sea_cfg) -> dict:
    methods = {}
    for m in sea.methods:
        methods[m.name] = {
            "rms_arcsec": _triple(_SHIP, m.rms_arcsec("all")),
            "rms_image_level_arcsec": _triple(_SHIP, m.rms_arcsec("image")),
            "rms_centroid_level_arcsec": _triple(_SHIP, m.rms_arcsec("centroid")),
            "seed_rms_arcsec": _triple(_SHIP, seed_rms_arcsec(m.name)), "n_epochs": len(m.t_s), "n_solved": m.n_solved}
    sensors = {s.name: {"n_frames": s.n_frames, "n_image_level": s.n_image_level, "n_solved": s.n_solved,
                        "median_stars_used": {k: _num(v, 1) for k, v in s.stars_used.items()},
                        "median_star_sigma_arcsec": {k: _num(v) for k, v in s.star_sigma_arcsec.items()},
                        "failures": list(s.failures)}
               for s in sea.sensors}
    return {"label": sea_cfg.label, "start_utc": sea_cfg.start_utc, "fore_aft_sensor": sea.fore_aft_sensor,
            "athwartship_sensor": sea.athwartship_sensor, "methods": methods, "sensors": sensors}


def results_dict(result) -> dict:
    """JSON-able results of a :class:`~shipstar._demo.DemoResult` (units in every key)."""
    model = {name: {"predicted_rms_arcsec": _triple(_SHIP, v["predicted"]),
                    "measured_rms_arcsec": _triple(_SHIP, v["measured"])}
             for name, v in result.layout.session_rms_arcsec.items()}
    return {"quick": result.quick, "out_dir": str(result.out_dir), "report": str(result.report_path),
            "dock": _dock_dict(result.dock, result.dock_config), "sea": _sea_dict(result.sea, result.sea_config),
            "error_model_centroid_level": model, "timing_s": {k: round(v, 2) for k, v in result.timing_s.items()}}


def _f(x, width: int = 8, nd: int = 2) -> str:
    x = float(x) if x is not None else math.nan
    if not math.isfinite(x):
        return f"{'-':>{width}}"
    return f"{0.0 if abs(x) < 0.5 * 10 ** -nd else x:{width}.{nd}f}"          # no "-0.00"


def _dock_lines(result) -> list:
    lines = [f"Installation calibration in dock ({result.dock_config.label}; {result.dock[0].n_frames} frames per "
             f"sensor, {result.dock[0].n_image_level} rendered as images)",
             f"{'sensor':<7}{'angle':<6}{'true (deg)':>13}{'estimated':>13}{'bias':>8}{'std':>8}{'sem':>8}"
             f"{'seed std':>10}   ('' = arcsec)"]
    for d in result.dock:
        seed = SEED_INSTALL_STD_ARCSEC.get(d.name, (None,) * 3)
        inst = d.installation
        for k, a in enumerate(_ANGLES):
            lines.append(f"{d.name if k == 0 else '':<7}{a:<6}{d.true_deg[k]:13.5f}{d.estimated_deg[k]:13.5f}"
                         f"{_f(d.bias_arcsec[k])}{_f(inst.std_arcsec[k])}{_f(inst.sem_arcsec[k])}{_f(seed[k], 10)}")
    return lines


def _sea_lines(result) -> list:
    sea = result.sea
    n, n_img = sea.sensors[0].n_frames, sea.sensors[0].n_image_level
    lines = [f"Ship attitude at sea ({result.sea_config.label}; {n} frames per sensor: {n_img} rendered as images "
             f"(motion smear), {n - n_img} at centroid level)",
             f"{'':<11}{'RMS, image level':>26}{'RMS, centroid level':>26}{'seeds (real ships)':>26}",
             f"{'method':<11}" + f"{'heading':>10}{'pitch':>8}{'roll':>8}" * 3 + "   (arcsec)"]
    for m in sea.methods:
        img, cen, seed = m.rms_arcsec("image"), m.rms_arcsec("centroid"), seed_rms_arcsec(m.name) or (None,) * 3
        lines.append(f"{m.name:<11}" + "".join(_f(v, 10 if k % 3 == 0 else 8) for k, v in
                                              enumerate([*img, *cen, *seed])))
    return lines


def results_text(result) -> str:
    """The human-readable results table."""
    head = ("shipstar demo: simulated sessions against their truth, beside the seeds' published figures.\n"
            "The seeds' figures come from real sessions (theodolite heading, deck flexure, clocks, real optics);\n"
            "the simulation has none of those errors, so it shows what the algorithms reach, not a real ship.")
    roles = f"seed rule: pitch from {result.sea.fore_aft_sensor}, roll from {result.sea.athwartship_sensor}, " \
            "heading averaged (seed 003); joint: one weighted solution of all stars"
    body = _dock_lines(result) + [""] + _sea_lines(result) + [roles]
    return head + "\n\n" + "\n".join(body) + "\n"

