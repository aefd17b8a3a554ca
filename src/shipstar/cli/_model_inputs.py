"""The model inputs every refraction/Earth-orientation command states: ``--eop FILE``,
relative humidity given or defaulted, the camera's wavelength, and the documented input
uncertainties of the total-uncertainty budget (docs/uncertainty.md)."""

from __future__ import annotations

import math

from shipstar.cli._common import finite_float

__all__ = ["add_eop_argument", "apply_eop", "add_model_input_arguments", "humidity", "input_sigmas",
           "installation_with_uncertainty", "uncertainty_report", "print_uncertainty", "ship_uncertainty",
           "weather_humidity_source", "add_measure_uncertainty", "print_measure_uncertainty"]


def _nonneg(text: str) -> float:
    import argparse

    v = finite_float(text)
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return v


def add_eop_argument(p) -> None:
    p.add_argument("--eop", metavar="FILE", default=None,
                   help="IERS finals2000A table newer than the packaged one (e.g. finals2000A.all from "
                        "https://datacenter.iers.org); recorded in the outputs")


def apply_eop(args) -> str:
    """Use ``--eop FILE`` (if given) for every Earth orientation; the source in use."""
    from shipstar.sky.eop import eop_source, set_eop_file

    if getattr(args, "eop", None):
        return set_eop_file(args.eop)
    return eop_source()


def add_model_input_arguments(p, *, dock: bool) -> None:
    """``--eop``, the input uncertainties, and ``--relative-humidity`` defaulting to
    "not given" (call after the weather arguments)."""
    from shipstar.calibrate.uncertainty import InputSigmas

    d = InputSigmas()
    add_eop_argument(p)
    g = p.add_argument_group("input uncertainties (1 sigma; docs/uncertainty.md)")
    g.add_argument("--pressure-sigma-hpa", type=_nonneg, default=d.pressure_hpa,
                   help=f"barometer (default {d.pressure_hpa:g})")
    g.add_argument("--temperature-sigma-c", type=_nonneg, default=d.temperature_c,
                   help=f"air temperature near the sensor (default {d.temperature_c:g})")
    g.add_argument("--humidity-sigma", type=_nonneg, default=d.relative_humidity,
                   help=f"relative humidity when given (default {d.relative_humidity:g}; not given: 0 is "
                        "assumed with sigma 0.5)")
    if dock:
        g.add_argument("--heading-sigma-arcsec", type=_nonneg, default=d.heading_arcsec,
                       help=f"dock theodolite heading (default {d.heading_arcsec:g})")
        g.add_argument("--level-sigma-arcsec", type=_nonneg, default=d.level_arcsec,
                       help=f"dock levels, pitch and roll each (default {d.level_arcsec:g})")
    p.set_defaults(relative_humidity=None)


def humidity(args) -> tuple:
    """``(relative_humidity, source)``: the flag's value and ``"given"``, or 0 and ``"default"``."""
    rh = getattr(args, "relative_humidity", None)
    return (0.0, "default") if rh is None else (float(rh), "given")


def input_sigmas(args, camera):
    from shipstar.calibrate.uncertainty import InputSigmas

    d = InputSigmas()
    return InputSigmas(pressure_hpa=getattr(args, "pressure_sigma_hpa", d.pressure_hpa),
                       temperature_c=getattr(args, "temperature_sigma_c", d.temperature_c),
                       relative_humidity=getattr(args, "humidity_sigma", d.relative_humidity),
                       wavelength_um=camera.wavelength_sigma_um,
                       heading_arcsec=getattr(args, "heading_sigma_arcsec", d.heading_arcsec),
                       level_arcsec=getattr(args, "level_sigma_arcsec", d.level_arcsec))


def installation_with_uncertainty(args, camera, inst, frames):
    """``inst`` with the dock's refraction inputs recorded (humidity and its source,
    wavelength, EOP source) and its total uncertainty and budget (docs/uncertainty.md)."""
    from dataclasses import replace

    from shipstar.calibrate.uncertainty import installation_budget, total_arcsec
    from shipstar.sky.apparent import Site
    from shipstar.sky.eop import earth_orientation, eop_source
    from shipstar.sky.refraction import Weather

    rh, source = humidity(args)
    d = replace(inst.dock, relative_humidity=rh, humidity_source=source, wavelength_um=camera.wavelength_um,
                eop_source=eop_source())
    inst = replace(inst, dock=d)
    if inst.n_used < 1 or not all(math.isfinite(x) for x in inst.sem_arcsec):
        return inst
    mid = frames[len(frames) // 2]
    site = Site(d.lat_rad, d.lon_rad, d.height_m, d.xi_rad, d.eta_rad)
    weather = Weather(d.pressure_hpa, d.temperature_c, rh, camera.wavelength_um)
    eop = earth_orientation(mid.utc_jd1, mid.utc_jd2)
    model = d.refraction_model or "erfa"
    C_hs = d.C_hor_from_deck @ inst.C_deck_from_sensor
    rows = installation_budget(camera, C_hs, d, weather, model, input_sigmas(args, camera),
                               utc_jd1=mid.utc_jd1, utc_jd2=mid.utc_jd2, site=site, eop=eop,
                               dut1_sigma_s=d.dut1_error_s, pm_sigma_arcsec=d.polar_motion_error_arcsec,
                               humidity_given=source == "given")
    return replace(inst, total_arcsec=total_arcsec(inst.sem_arcsec, rows),
                   uncertainty=tuple(r.as_dict() for r in rows))


def uncertainty_report(inst) -> dict:
    """JSON keys of ``calibrate install``: total uncertainty, budget, refraction inputs."""
    d = inst.dock
    return {"total_arcsec": dict(zip(("az", "el", "roll"), inst.total_arcsec)),
            "uncertainty": list(inst.uncertainty),
            "refraction_inputs": {"pressure_hpa": d.pressure_hpa, "temperature_c": d.temperature_c,
                                  "relative_humidity": d.relative_humidity, "humidity_source": d.humidity_source,
                                  "wavelength_um": d.wavelength_um, "refraction_model": d.refraction_model},
            "eop_source": d.eop_source}


def print_uncertainty(rep: dict) -> None:
    t, r = rep["total_arcsec"], rep["refraction_inputs"]
    hum = f"{r['relative_humidity']:g}" + (" (not given: dry air assumed)" if r["humidity_source"] == "default"
                                           else "")
    print(f"  refraction inputs: {r['pressure_hpa']:g} hPa, {r['temperature_c']:g} C, humidity {hum}, "
          f"wavelength {r['wavelength_um']:g} um, model {r['refraction_model']}; Earth orientation from "
          f"{rep['eop_source']}")
    print(f"  total uncertainty (sem and the model budget, docs/uncertainty.md): az {t['az']:.3f}'' "
          f"el {t['el']:.3f}'' roll {t['roll']:.3f}''")


def ship_uncertainty(configs, weather_table, track, model: str, start_jd, sigmas_args, humidity_source: str,
                     methods: dict) -> dict:
    """``measure``'s budget: per sensor, the systematic effects on (heading, pitch, roll)
    (:func:`shipstar.calibrate.uncertainty.ship_budget`) at the session's start, and per
    method ``total = sqrt(median_sigma**2 + systematic**2)``, the systematic of a method of
    several sensors taken as the largest of its sensors' (they share the weather and Earth
    orientation, so their errors do not average out)."""
    import numpy as np

    from dataclasses import replace

    from shipstar.calibrate.uncertainty import budget_as_dict, ship_budget, total_arcsec
    from shipstar.pipeline import eop_quality
    from shipstar.sky.eop import earth_orientation, eop_source

    jd1, jd2 = start_jd
    q = eop_quality([jd1], [jd2])
    site = track.site(jd1, jd2)
    eop = earth_orientation(jd1, jd2)
    names = ("heading", "pitch", "roll")
    sensors, sys_by = {}, {}
    for c in configs:
        weather = replace(weather_table.weather(jd1, jd2), wavelength_um=c.camera.wavelength_um)
        rows = ship_budget(c.camera, c.installation, weather, model, input_sigmas(sigmas_args, c.camera),
                           utc_jd1=jd1, utc_jd2=jd2, site=site, eop=eop, dut1_sigma_s=q.dut1_error_s,
                           pm_sigma_arcsec=q.polar_motion_error_arcsec, humidity_given=humidity_source == "given")
        sys_by[c.name] = np.array(total_arcsec((0.0, 0.0, 0.0), rows))
        sensors[c.name] = {**budget_as_dict((0.0, 0.0, 0.0), rows, names), "wavelength_um": c.camera.wavelength_um}
        sensors[c.name]["systematic_arcsec"] = sensors[c.name].pop("total_arcsec")
        sensors[c.name].pop("sem_arcsec")
    worst = np.max(np.array(list(sys_by.values())), axis=0)
    out_methods = {}
    for m, b in methods.items():
        sys = sys_by.get(m.removeprefix("single:"), worst)
        sig = np.array([np.nan if v is None else v for v in b.get("median_sigma_arcsec", [None] * 3)], float)
        out_methods[m] = {"median_sigma_arcsec": dict(zip(names, map(float, sig))),
                          "systematic_arcsec": dict(zip(names, map(float, sys))),
                          "total_arcsec": dict(zip(names, map(float, np.hypot(sig, sys))))}
    return {"sensors": sensors, "methods": out_methods, "relative_humidity_source": humidity_source,
            "eop_source": eop_source()}


def weather_humidity_source(args) -> str:
    """``"given"`` or ``"default"``: the --relative-humidity flag, or the weather CSV's
    ``relative_humidity`` column."""
    path = getattr(args, "weather", None)
    if not path:
        return humidity(args)[1]
    try:
        with open(path, encoding="utf-8") as fh:
            header = next((ln for ln in fh if ln.strip() and not ln.lstrip().startswith("#")), "")
    except (OSError, UnicodeDecodeError):
        return "default"
    return "given" if "relative_humidity" in [c.strip() for c in header.split(",")] else "default"


def add_measure_uncertainty(summary: dict, args, job) -> None:
    """``summary["uncertainty"]``: per sensor the systematic budget of (heading, pitch,
    roll), per method the median formal sigma, the systematic and their total."""
    summary["uncertainty"] = ship_uncertainty(job.configs, job.weather, job.track, job.options.refraction_model,
                                              job.start_utc_jd, args, weather_humidity_source(args),
                                              summary.get("methods", {}))
    summary.setdefault("eop", {})["source"] = summary["uncertainty"]["eop_source"]


def print_measure_uncertainty(summary: dict) -> None:
    u = summary.get("uncertainty")
    if not u:
        return
    print("method          total uncertainty heading/pitch/roll ('') = formal sigma (+) model budget "
          "(docs/uncertainty.md)")
    for m, b in u["methods"].items():
        tot = "/".join(f"{v:.2f}" for v in b["total_arcsec"].values())
        sys = "/".join(f"{v:.2f}" for v in b["systematic_arcsec"].values())
        print(f"{m:15s} {tot:>22s}   (model budget {sys})")
    hum = "given" if u["relative_humidity_source"] == "given" else "not given: 0 (dry air) assumed"
    waves = ", ".join(f"{n} {s['wavelength_um']:g} um" for n, s in u["sensors"].items())
    print(f"refraction inputs: relative humidity {hum}; wavelength {waves}; Earth orientation from {u['eop_source']}")
