"""``shipstar apparent``: observed places of stars in the ship's horizontal frame."""

from __future__ import annotations

import argparse
import sys

from shipstar.cli._common import emit_json, finite_float, in_range, latitude_deg, longitude_deg

EPILOG = """\
example (the seeds' dock, Jiangyin, 2013-03-15 20:16 local time):
  shipstar apparent --time 2013-03-15T12:16:00 --lat-deg 31.9 --lon-deg 120.3 \\
      --mag-limit 2 --pressure-hpa 1021.7 --temperature-c 11.1
  shipstar apparent --time 2013-03-15T12:16:00 --lat-deg 31.9 --lon-deg 120.3 \\
      --hip 32349 24436 --refraction erfa --json

Azimuth is from north toward east, elevation above the astronomical horizon (the plumb
line: give the deflection of the vertical with --xi-arcsec/--eta-arcsec; default 0 = the
ellipsoid normal).  Places are observed (refracted) for elevations the refraction model
covers (5 deg; 10 deg for 'erfa'); stars between the horizon and that limit are omitted
with a note, or refused if named with --hip (use --refraction none).  Stars below the
horizon are omitted unless named with --hip (then shown unrefracted, flagged).
Earth orientation comes from the IERS tables shipped with astropy-iers-data (offline);
its quality (measured, predicted, extrapolated) is reported.
"""

DEFAULT_MAG_LIMIT = 3.0


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "apparent", help="observed azimuth/elevation of stars at a time and place",
        description="Observed places of Hipparcos stars in the horizontal frame "
                    "(X north, Y up, Z east) at a UTC time and ship position.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--time", required=True, metavar="ISO",
                   help="UTC time, ISO 8601, e.g. 2013-03-15T12:16:00 (optional Z, fractions)")
    p.add_argument("--lat-deg", required=True, type=latitude_deg, help="geodetic latitude (deg)")
    p.add_argument("--lon-deg", required=True, type=longitude_deg, help="longitude, east positive (deg)")
    p.add_argument("--height-m", type=finite_float, default=0.0, help="height above WGS84 (m)")
    p.add_argument("--xi-arcsec", type=finite_float, default=0.0,
                   help="deflection of the vertical, north-south component (arcsec, default 0)")
    p.add_argument("--eta-arcsec", type=finite_float, default=0.0,
                   help="deflection of the vertical, east-west component (arcsec, default 0)")
    p.add_argument("--refraction", choices=("erfa", "almanac", "none"), default="erfa",
                   help="refraction model (default erfa, good to 0.02'' above 15 deg; almanac = the seeds' model)")
    p.add_argument("--pressure-hpa", type=in_range("pressure_hpa"), default=1013.25, help="air pressure (hPa)")
    p.add_argument("--temperature-c", type=in_range("temperature_c"), default=10.0, help="air temperature (C)")
    p.add_argument("--relative-humidity", type=in_range("relative_humidity"), default=0.0,
                   help="relative humidity 0..1 (erfa model only)")
    p.add_argument("--wavelength-um", type=in_range("wavelength_um"), default=0.55,
                   help="effective wavelength (um, erfa model only)")
    p.add_argument("--hip", type=int, nargs="+", metavar="N", help="only these HIP numbers")
    p.add_argument("--mag-limit", type=finite_float, default=None,
                   help=f"faintest Hp magnitude (default {DEFAULT_MAG_LIMIT:g}; not with --hip)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    from shipstar.cli._model_inputs import add_eop_argument

    add_eop_argument(p)
    p.set_defaults(run=run)
    return p


def _select(args):
    """``(catalog, index)``: the named stars in the given order, or the bright ones by mag."""
    import numpy as np

    from shipstar.errors import ShipstarError
    from shipstar.sky import catalog

    if args.hip:
        if args.mag_limit is not None:
            raise ShipstarError("give either --hip or --mag-limit, not both")
        full = catalog.load_hipparcos()
        hips = list(dict.fromkeys(args.hip))
        return full, full.index_of_hip(hips)
    mag_limit = DEFAULT_MAG_LIMIT if args.mag_limit is None else args.mag_limit
    nav = catalog.navigation_catalog(mag_limit)
    return nav, np.argsort(nav.mag, kind="stable")


def _places(ctx, cat, index, weather, model, named):
    """Rows (dicts) of observed places, and notes about omitted stars."""
    import numpy as np

    from shipstar.errors import ShipstarError
    from shipstar.frames import az_el_from_unit
    from shipstar.sky.refraction import min_true_el_rad, refract_hor
    from shipstar.units import RAD2DEG

    v_true = ctx.hor_from_catalog(cat, index=index)
    _, el_true = az_el_from_unit(v_true)
    below = el_true < 0.0
    lo = 0.0 if model == "none" else min_true_el_rad(weather, model)
    refract = el_true >= lo
    too_low = ~below & ~refract
    notes = []
    if too_low.any() and named:
        bad = ", ".join(f"HIP {cat.hip[i]} at {e * RAD2DEG:.2f} deg"
                        for i, e in zip(index[too_low], el_true[too_low]))
        raise ShipstarError(
            f"{bad}: below {lo * RAD2DEG:.2f} deg true elevation, the lowest refraction model "
            f"'{model}' handles; use --refraction none for unrefracted places")
    if too_low.any():
        notes.append(f"{int(too_low.sum())} star(s) between the horizon and {lo * RAD2DEG:.2f} deg "
                     f"omitted: refraction model '{model}' does not cover them")
    keep = np.ones(len(index), bool) if named else ~below & ~too_low
    v_obs = v_true.copy()
    if model != "none" and refract.any():
        v_obs[refract] = refract_hor(v_true[refract], weather, model)
    az, el = az_el_from_unit(v_obs)
    rows = [
        {"hip": int(cat.hip[i]), "mag": float(cat.mag[i]), "az_deg": float(a * RAD2DEG),
         "el_deg": float(e * RAD2DEG), "refracted": bool(r and model != "none"),
         "below_horizon": bool(b)}
        for i, a, e, r, b in zip(index[keep], az[keep], el[keep], refract[keep], below[keep])
    ]
    return rows, notes


def _human(result) -> str:
    site, eop, refr = result["site"], result["eop"], result["refraction"]
    lines = [
        f"time {result['time_utc']}  lat {site['lat_deg']:.6f}  lon {site['lon_deg']:.6f} deg  "
        f"height {site['height_m']:g} m",
        f"Earth orientation: {eop['quality']}, UT1-UTC {eop['dut1_s']:+.5f} s "
        f"(+-{eop['dut1_error_s']:.5f} s), polar motion x {eop['xp_arcsec']:.4f} "
        f"y {eop['yp_arcsec']:.4f} arcsec",
        (f"refraction: {refr['model']}, {refr['pressure_hpa']:g} hPa, {refr['temperature_c']:g} C"
         if refr["model"] != "none" else "refraction: none (true places)"),
        f"deflection of the vertical: xi {site['xi_arcsec']:g}, eta {site['eta_arcsec']:g} arcsec"
        + ("  (0 = ellipsoid normal)" if site["xi_arcsec"] == site["eta_arcsec"] == 0 else ""),
        "",
        f"{'HIP':>7} {'Hp':>6} {'az_deg':>12} {'el_deg':>12}  note",
    ]
    for s in result["stars"]:
        note = "below horizon, unrefracted" if s["below_horizon"] else (
            "" if s["refracted"] else "unrefracted")
        row = f"{s['hip']:>7} {s['mag']:>6.2f} {s['az_deg']:>12.6f} {s['el_deg']:>12.6f}  {note}"
        lines.append(row.rstrip())
    if not result["stars"]:
        lines.append("(no stars)")
    lines += [f"note: {n}" for n in result["notes"]]
    return "\n".join(lines)


def run(args) -> int:
    import warnings

    from shipstar.errors import AccuracyWarning
    from shipstar.sky.apparent import Site, frame_context
    from shipstar.sky.refraction import Weather
    from shipstar.sky.time import iso_from_utc_jd, utc_jd_from_iso
    from shipstar.units import RAD2ASEC

    jd = utc_jd_from_iso(args.time)
    site = Site.from_deg(args.lat_deg, args.lon_deg, args.height_m, args.xi_arcsec, args.eta_arcsec)
    weather = Weather(args.pressure_hpa, args.temperature_c, args.relative_humidity, args.wavelength_um)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", AccuracyWarning)
        ctx = frame_context(*jd, site)
        cat, index = _select(args)
        stars, notes = _places(ctx, cat, index, weather, args.refraction, named=bool(args.hip))
    messages = list(dict.fromkeys(str(w.message) for w in caught))
    for msg in messages:
        print(f"shipstar apparent: warning: {msg}", file=sys.stderr)
    eop = ctx.eop
    result = {
        "time_utc": iso_from_utc_jd(*jd, 3),
        "site": {"lat_deg": args.lat_deg, "lon_deg": args.lon_deg, "height_m": args.height_m,
                 "xi_arcsec": args.xi_arcsec, "eta_arcsec": args.eta_arcsec},
        "refraction": {"model": args.refraction, "pressure_hpa": weather.pressure_hpa,
                       "temperature_c": weather.temperature_c,
                       "relative_humidity": weather.relative_humidity,
                       "wavelength_um": weather.wavelength_um},
        "eop": {"quality": eop.quality, "dut1_s": eop.dut1_s, "dut1_error_s": eop.dut1_error_s,
                "xp_arcsec": eop.xp_rad * RAD2ASEC, "yp_arcsec": eop.yp_rad * RAD2ASEC,
                "polar_motion_error_arcsec": eop.polar_motion_error_rad * RAD2ASEC},
        "stars": stars,
        "notes": notes,
        "warnings": messages,
    }
    if args.json:
        emit_json(result)
    else:
        print(_human(result))
    return 0
