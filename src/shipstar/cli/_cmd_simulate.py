"""``shipstar simulate``: render a synthetic star-sensor frame (FITS) and its truth (JSON)."""

from __future__ import annotations

import argparse

from shipstar.cli._common import (angle_deg, emit_json, finite_float, in_range, int_in_range, latitude_deg,
                                  longitude_deg, rng_seed)
from shipstar.errors import ShipstarError

__all__ = ["register"]

_EPILOG = """\
Attitude forms (exactly one):
  sensor in ICRS:  --ra-deg --dec-deg [--roll-deg]   (roll: position angle of image up,
                   from north through east).  Alone: "space" geometry at --time (default
                   J2000.0), no aberration or refraction.  With --time --lat-deg --lon-deg:
                   the same pointing seen from that site through the atmosphere.
  ship:            --heading-deg [--pitch-deg --ship-roll-deg] --install-az-deg
                   --install-el-deg [--install-roll-deg] with --time --lat-deg --lon-deg.

Writes OUT (FITS, one uint16 HDU; FITS standard times: DATE-OBS = DATE-BEG = start of the
exposure, DATE-AVG = mid-exposure UTC = --time, DATE-END, EXPTIME) and OUT's name with
.truth.json instead of .fits (attitude, every star's HIP number and true pixel position).

examples:
  shipstar simulate --camera A1 --ra-deg 83.8 --dec-deg -5.4 --roll-deg 0 --seed 1 --out orion.fits
  shipstar simulate --camera A1 --heading-deg 46.4746 --install-az-deg 185.1093 \\
      --install-el-deg 39.3734 --install-roll-deg -0.2262 --time 2013-03-15T12:16:00 \\
      --lat-deg 31.9 --lon-deg 120.3 --pressure-hpa 1021.7 --temperature-c 11.1 \\
      --seed 7 --out dock_a1.fits --json
"""


_count = int_in_range(0, 1000)


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "simulate", help="render a synthetic star sensor frame (FITS) and its truth (JSON)",
        description="Render a synthetic frame of a star sensor with known truth: Hipparcos stars by "
                    "magnitude (camera photon budget), Gaussian PSF, sky, dark, hot pixels, shot and read "
                    "noise, saturation, ADC; on Earth apparent places and per-star refraction.",
        epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--camera", default="A1", metavar="NAME|FILE",
                   help="camera preset (A1, A2, seed002, seed004) or camera TOML file (default A1)")
    a = p.add_argument_group("sensor attitude in ICRS")
    a.add_argument("--ra-deg", type=angle_deg, metavar="DEG", help="boresight right ascension")
    a.add_argument("--dec-deg", type=angle_deg, metavar="DEG", help="boresight declination")
    a.add_argument("--roll-deg", type=angle_deg, metavar="DEG", help="position angle of image up (default 0: north up)")
    s = p.add_argument_group("ship attitude and installation (needs --time and a site)")
    s.add_argument("--heading-deg", type=in_range("heading_deg"), metavar="DEG", help="ship heading, from north through east")
    s.add_argument("--pitch-deg", type=in_range("pitch_deg"), metavar="DEG", help="ship pitch, bow up positive (default 0)")
    s.add_argument("--ship-roll-deg", type=in_range("roll_deg", label="ship_roll_deg"), metavar="DEG", help="ship roll, starboard down positive (default 0)")
    s.add_argument("--install-az-deg", type=in_range("install_az_deg"), metavar="DEG", help="installation azimuth from the bow to starboard")
    s.add_argument("--install-el-deg", type=in_range("install_el_deg"), metavar="DEG", help="installation elevation above the deck")
    s.add_argument("--install-roll-deg", type=in_range("install_roll_deg"), metavar="DEG", help="sensor roll about its boresight (default 0)")
    s.add_argument("--deck-rate-deg-per-s", type=finite_float, nargs=3, metavar=("WX", "WY", "WZ"),
                   help="ship angular rate about the deck axes (bow, up, starboard): motion smear")
    t = p.add_argument_group("time, site and weather")
    t.add_argument("--time", metavar="ISO", help="mid-exposure UTC, e.g. 2013-03-15T12:16:00")
    t.add_argument("--lat-deg", type=latitude_deg, metavar="DEG", help="geodetic latitude")
    t.add_argument("--lon-deg", type=longitude_deg, metavar="DEG", help="longitude, east positive")
    t.add_argument("--height-m", type=finite_float, metavar="M", help="height above the WGS84 ellipsoid (default 0)")
    t.add_argument("--pressure-hpa", type=in_range("pressure_hpa"), metavar="HPA", help="air pressure at the sensor (default 1013.25)")
    t.add_argument("--temperature-c", type=in_range("temperature_c"), metavar="C", help="air temperature (default 10)")
    t.add_argument("--relative-humidity", type=finite_float, metavar="FRACTION", help="0..1, erfa model only (default 0)")
    t.add_argument("--refraction", choices=("erfa", "almanac", "none"), help="refraction model (default erfa; almanac = the seeds' model)")
    o = p.add_argument_group("scene and output")
    o.add_argument("--mag-limit", type=finite_float, metavar="MAG", default=None, help="faintest Hp magnitude (default 8)")
    o.add_argument("--seed", type=rng_seed, metavar="N", help="noise seed (default: random, reported)")
    o.add_argument("--sensor-rate-deg-per-s", type=finite_float, nargs=3, metavar=("WX", "WY", "WZ"),
                   help="sensor angular rate about its axes (boresight, up, right): motion smear")
    o.add_argument("--planets", type=_count, metavar="N", default=0, help="random bright point sources (false stars)")
    o.add_argument("--trails", type=_count, metavar="N", default=0, help="random satellite trails")
    o.add_argument("--cosmic-rays", type=_count, metavar="N", default=0, help="random cosmic-ray hits")
    o.add_argument("--hot-pixel-fraction", type=finite_float, metavar="FRACTION", default=None,
                   help="fraction of hot pixels (default 2e-5)")
    o.add_argument("--out", required=True, metavar="FRAME.fits", help="FITS file to write")
    o.add_argument("--json", action="store_true", help="print one JSON object describing the result")
    from shipstar.cli._model_inputs import add_eop_argument

    add_eop_argument(p)
    p.set_defaults(run=run)
    return p


def _form(args) -> str:
    icrs = [args.ra_deg, args.dec_deg, args.roll_deg]
    ship = [args.heading_deg, args.pitch_deg, args.ship_roll_deg, args.install_az_deg,
            args.install_el_deg, args.install_roll_deg, args.deck_rate_deg_per_s]
    if any(v is not None for v in icrs) and any(v is not None for v in ship):
        raise ShipstarError("give either the ICRS attitude (--ra-deg ...) or the ship attitude "
                            "(--heading-deg ...), not both")
    if any(v is not None for v in ship):
        missing = [f for f, v in (("--heading-deg", args.heading_deg), ("--install-az-deg", args.install_az_deg),
                                  ("--install-el-deg", args.install_el_deg)) if v is None]
        if missing:
            raise ShipstarError(f"the ship attitude form needs {', '.join(missing)}")
        return "ship"
    if args.ra_deg is None or args.dec_deg is None:
        raise ShipstarError("give the attitude: --ra-deg and --dec-deg, or --heading-deg, --install-az-deg "
                            "and --install-el-deg")
    if not -90.0 <= args.dec_deg <= 90.0:
        raise ShipstarError(f"declination must be within [-90, 90] deg, got {args.dec_deg}")
    return "icrs"


def _site_and_weather(args, form: str):
    from shipstar.sky.apparent import Site
    from shipstar.sky.refraction import Weather

    site_flags = [args.lat_deg, args.lon_deg, args.height_m]
    weather_flags = [args.pressure_hpa, args.temperature_c, args.relative_humidity, args.refraction]
    if all(v is None for v in site_flags) and form == "icrs":
        if any(v is not None for v in weather_flags):
            raise ShipstarError("weather and refraction flags need a site (--lat-deg, --lon-deg, --time)")
        return None, None, "none"
    if args.lat_deg is None or args.lon_deg is None or args.time is None:
        raise ShipstarError("a frame on Earth needs --time, --lat-deg and --lon-deg")
    site = Site.from_deg(args.lat_deg, args.lon_deg, 0.0 if args.height_m is None else args.height_m)
    weather = Weather(
        pressure_hpa=1013.25 if args.pressure_hpa is None else args.pressure_hpa,
        temperature_c=10.0 if args.temperature_c is None else args.temperature_c,
        relative_humidity=0.0 if args.relative_humidity is None else args.relative_humidity)
    return site, weather, args.refraction or "erfa"


def _simulate(args):
    import numpy as np

    from shipstar.camera import load_camera
    from shipstar.frames import C_icrs_from_sensor
    from shipstar.simulate import (
        DEFAULT_MAG_LIMIT,
        HOT_PIXEL_FRACTION,
        ShipPose,
        random_false_objects,
        simulate_frame,
    )
    from shipstar.units import DEG2RAD

    form = _form(args)
    camera = load_camera(args.camera)
    site, weather, model = _site_and_weather(args, form)
    seed = args.seed if args.seed is not None else int(np.random.SeedSequence().generate_state(1, np.uint64)[0]) >> 1
    rate = None if args.sensor_rate_deg_per_s is None else np.array(args.sensor_rate_deg_per_s) * DEG2RAD
    attitude = {}
    if form == "ship":
        ship = ShipPose.from_deg(args.heading_deg, args.pitch_deg or 0.0, args.ship_roll_deg or 0.0,
                                 args.install_az_deg, args.install_el_deg, args.install_roll_deg or 0.0)
        attitude["ship"] = ship
        if args.deck_rate_deg_per_s is not None:
            deck = ship.omega_sensor_from_deck(np.array(args.deck_rate_deg_per_s) * DEG2RAD)
            rate = deck if rate is None else rate + deck
    else:
        attitude["C_icrs_from_sensor"] = C_icrs_from_sensor(args.ra_deg * DEG2RAD, args.dec_deg * DEG2RAD,
                                                            (args.roll_deg or 0.0) * DEG2RAD)
    objects = random_false_objects(camera, np.random.default_rng([seed, 1]), planets=args.planets,
                                   trails=args.trails, cosmic_rays=args.cosmic_rays)
    return simulate_frame(
        camera, utc_iso=args.time, site=site, weather=weather, refraction_model=model,
        mag_limit=DEFAULT_MAG_LIMIT if args.mag_limit is None else args.mag_limit, seed=seed,
        omega_sensor_rad_per_s=rate, false_objects=objects,
        hot_pixel_fraction=HOT_PIXEL_FRACTION if args.hot_pixel_fraction is None else args.hot_pixel_fraction,
        **attitude)


def run(args) -> int:
    from pathlib import Path

    from shipstar.frames import ra_dec_roll_from_C_icrs_from_sensor
    from shipstar.simulate import write_frame
    from shipstar.units import RAD2DEG

    if Path(args.out).suffix.lower() not in (".fits", ".fit", ".fts"):
        raise ShipstarError(f"--out must name a FITS file (.fits, .fit or .fts), got {args.out!r}")
    frame = _simulate(args)
    fits_path, truth_path = write_frame(frame, args.out)
    ra, dec, roll = (float(v) * RAD2DEG for v in ra_dec_roll_from_C_icrs_from_sensor(frame.C_icrs_from_sensor))
    result = {"fits_path": str(fits_path), "truth_path": str(truth_path), "camera_name": frame.camera_name,
              "utc_mid_exposure": frame.utc_iso, "frame": frame.frame, "seed": frame.seed,
              "n_stars": len(frame.stars), "ra_deg": ra, "dec_deg": dec, "roll_deg": roll}
    if args.json:
        emit_json(result)
    else:
        print(f"wrote {fits_path} and {truth_path}: {len(frame.stars)} stars, camera {frame.camera_name}, "
              f"{frame.utc_iso}, boresight RA {ra:.4f} deg Dec {dec:.4f} deg roll {roll:.4f} deg, seed {frame.seed}")
    return 0
