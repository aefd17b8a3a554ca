"""The real sky and the real ship (issue 14): one short image-level sea session per condition.

For each shipped conditions example (``cloud``, ``moon``, ``twilight``, ``seeing``,
``hot_pixels``, ``trails``, ``clock``, ``flexure``, ``distortion``), for ``realistic.toml``
and for a baseline without any condition, the session is rendered as FITS frames
(``shipstar simulate-session --kind sea --conditions NAME``) and measured by ``shipstar
measure`` (both sensors, the true rigid installations, the session's track and weather,
``--json --monitor``).  Printed per session:

- availability: solved share per sensor and the reasons of the frames lost (``clouded``,
  ``moon in field``, solver failures);
- eligible frames solved: the frames with at least 8 catalog stars detectable at SNR >= 12
  (from each frame's truth: the star's rendered electrons against shot noise of star, sky
  and dark current and the read noise over the PSF's and streak's noise area
  ``4 pi s^2 + 2 sqrt(pi) s L``) and how many of them solved;
- wrong solutions: solved single-sensor frames whose sensor attitude (the row's ship
  attitude through the installation file) is more than 60'' (rotation angle) from the
  frame's true ``C_hor_from_sensor`` (at the true exposure time, with the flexed mount:
  a clock offset or flexure is not counted as wrong) **and** more than 5 times the row's
  own sigma (the root sum square of its three sigmas): a wrong identification, not a
  frame with few stars whose stated sigma is 10-30''; printed as ``wrong/over``, ``over``
  the frames beyond 60'' alone;
- joint RMS heading / pitch / roll against the truth and RMS(error / sigma) per angle,
  **after the warm-up** (epochs at t >= ``--warmup-s``, default 4 s: the clock and flexure
  estimators need >= 30 epochs to settle, pipeline._mounts.MIN_EPOCHS);
- estimated against true clock offset (``time_offsets_s``) and flexure wave amplitude
  (``flexure.wave_amplitude_arcsec``, bow axis) of A2 relative to A1;
- the seeing estimate (per-sensor noise floor, when ``measure --json`` gives it).

``realistic-sky`` is realistic.toml's night (its start time: the same star fields, the
Moon's) without any condition: the control for ``realistic``.  The ``realistic`` row is
checked against the issue's targets (no wrong solution; every eligible frame solved;
joint RMS <= 1.5'' on each angle; clock offset within 0.3 ms; flexure amplitude within
20 %; RMS(error/sigma) within 0.8-1.25), PASS / FAIL.

Run: ``python benchmarks/bench_conditions.py [--duration-s 16] [--realistic-duration-s 120]
[--only realistic,clock] [--workdir DIR [--reuse | --evaluate-only]]``.  ``realistic`` and
``realistic-sky`` last ``--realistic-duration-s`` (default 120 s): the mounts' flexure
under a sparse, moonlit sky is known to ~1.4'' after 16 s and ~0.5'' after two minutes
(docs/pipeline.md), a night lasts hours; over 16 s every epoch shares one draw of that
error, so RMS(error/sigma) there is one sample of it, not the sigmas' calibration.  Rendering (~0.2 s a frame under conditions) of the next
session overlaps the measurement of the last one (two processes).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CASES = ("baseline", "cloud", "moon", "twilight", "seeing", "hot_pixels", "trails", "clock", "flexure",
         "distortion", "realistic-sky", "realistic")
#: realistic.toml's night without its conditions (only its start time, so the same stars are
#: in the fields): what the sky at that hour gives before cloud, Moon, seeing, clock, flexure.
REALISTIC_SKY_TOML = '''format = "shipstar-conditions"
format_version = 1
[session]
start_utc = "2013-03-26T19:00:00"
'''
WRONG_ARCSEC = 60.0
WRONG_SIGMAS = 5.0
SNR_MIN, MIN_STARS = 12.0, 8
TARGETS = {"rms_arcsec": 1.5, "clock_s": 3e-4, "flexure_rel": 0.2, "z": (0.8, 1.25)}


def _shipstar(*args) -> list:
    return [sys.executable, "-m", "shipstar", *map(str, args)]


def write_installations(root: Path) -> list:
    from shipstar.calibrate.installation import Installation, save_installation
    from shipstar.simulate._session import sea_session

    paths = []
    for s in sea_session(duration_s=1.0).sensors:
        p = root / f"{s.name}.install.toml"
        if not p.exists():
            save_installation(Installation.from_matrix(s.name, s.camera.name, s.C_deck_from_sensor), p)
        paths.append(p)
    return paths


def simulate_cmd(case: str, out: Path, duration_s: float) -> list:
    cmd = _shipstar("simulate-session", "--kind", "sea", "--out", out, "--duration-s", duration_s)
    if case == "realistic-sky":
        f = out.parent / "realistic-sky.toml"
        f.write_text(REALISTIC_SKY_TOML, encoding="utf-8")
        return cmd + ["--conditions", f]
    return cmd + ([] if case == "baseline" else ["--conditions", case])


def measure_cmd(d: Path, installs, windowed_full_frame_every: int = 0) -> list:
    return _shipstar("measure", "--sensor", f"A1={d / 'A1'}", "--sensor", f"A2={d / 'A2'}", "--install", *installs,
                     "--track", d / "track.csv", "--weather", d / "weather.csv", "--out", d / "attitude.csv",
                     "--monitor", d / "monitor.csv", "--json", "--workers", "1",
                     "--windowed-full-frame-every", str(windowed_full_frame_every))


# -- evaluation -------------------------------------------------------------------------------
def _eligible(truth_json: dict) -> bool:
    """At least MIN_STARS catalog stars detectable at SNR >= SNR_MIN in this frame."""
    cam = truth_json["camera"]
    t = float(truth_json["exposure_s"])
    sky = float((truth_json.get("conditions") or {}).get("sky_e_per_px_per_s") or cam["sky_e_per_px_per_s"])
    s = float(cam["psf_sigma_px"])
    per_px = (sky + float(cam["dark_e_per_s"])) * t + float(cam["read_noise_e"]) ** 2
    stars = truth_json["stars"]
    sig = np.asarray(stars["signal_e"], float)
    xy = np.asarray(stars["xy_px"], float).reshape(-1, 2)
    smear = np.linalg.norm(np.asarray(stars.get("smear_px", np.zeros((len(sig), 2))), float).reshape(-1, 2), axis=1)
    area = 4.0 * math.pi * s * s + 2.0 * math.sqrt(math.pi) * s * smear
    snr = sig / np.sqrt(sig + area * per_px)
    w, h = cam["width_px"], cam["height_px"]
    inside = (xy[:, 0] > 3) & (xy[:, 0] < w - 4) & (xy[:, 1] > 3) & (xy[:, 1] < h - 4)
    return int(np.count_nonzero((snr >= SNR_MIN) & inside)) >= MIN_STARS


def evaluate(d: Path, summary: dict, warmup_s: float, late_s: float = 8.0) -> dict:
    from shipstar.frames import C_hor_from_deck, wrap_pi
    from shipstar.pipeline import TruthTable
    from shipstar.sky.time import utc_jd_from_iso
    from shipstar.units import DEG2RAD, RAD2ASEC

    truth = TruthTable.read_csv(d / "truth.csv")
    with open(d / "attitude.csv", newline="") as fh:
        rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
    out = {"sensors": {}, "n_wrong": 0, "n_over": 0, "max_single_err": 0.0}
    single = {}
    err_j, sig_j, t_j = [], [], []
    for r in rows:
        solved = str(r["solved"]) == "1"
        if r["method"] == "single":
            single[(r["sensor"], r["frame"])] = r if solved else None
        if not solved or r["method"] != "joint" or float(r["t_s"]) < warmup_s:
            continue
        true = np.array(truth.angles_rad(*utc_jd_from_iso(r["time_utc"])))
        est = np.array([float(r[c]) for c in ("heading_deg", "pitch_deg", "roll_deg")]) * DEG2RAD
        e = wrap_pi(est - true) * RAD2ASEC
        if np.all(np.isfinite(e)):
            err_j.append(e)
            t_j.append(float(r["t_s"]))
            sig_j.append([float(r[c]) for c in ("sigma_heading_arcsec", "sigma_pitch_arcsec", "sigma_roll_arcsec")])
    err_j, sig_j = np.array(err_j).reshape(-1, 3), np.array(sig_j).reshape(-1, 3)
    out["n_joint"] = len(err_j)
    out["joint_rms"] = np.sqrt(np.mean(err_j ** 2, axis=0)) if len(err_j) else np.full(3, np.nan)
    out["z_rms"] = np.sqrt(np.mean((err_j / sig_j) ** 2, axis=0)) if len(err_j) else np.full(3, np.nan)
    late = np.array(t_j) >= late_s
    out["late_s"] = late_s
    out["joint_rms_late"] = np.sqrt(np.mean(err_j[late] ** 2, axis=0)) if late.any() else np.full(3, np.nan)
    out["z_rms_late"] = np.sqrt(np.mean((err_j[late] / sig_j[late]) ** 2, axis=0)) if late.any() else np.full(3, np.nan)
    # per frame, from its truth: eligible (>= 8 stars at SNR >= 12), solved, wrong (the sensor's
    # attitude, C_hor_from_deck(row) C_deck_from_sensor(installation file), more than 60'' from
    # the frame's true C_hor_from_sensor: that is at the true exposure time and with the flexed
    # mount, so a clock offset or flexure does not count as wrong)
    n_el = n_el_solved = 0
    for name, b in summary["sensors"].items():
        out["sensors"][name] = {k: b.get(k) for k in ("n_frames", "n_solved", "n_failed", "n_clouded",
                                                      "n_moon_in_field", "n_sun_in_field")}
        for tj in sorted((d / name).glob("*.truth.json")):
            t = json.loads(tj.read_text())
            r = single.get((name, tj.name[:-len(".truth.json")] + ".fits"))
            if _eligible(t):
                n_el += 1
                n_el_solved += int(r is not None)
            if r is None:
                continue
            C_ds = np.asarray((t.get("conditions") or {}).get("C_deck_from_sensor_nominal") or t["C_deck_from_sensor"])
            est = [float(r[c]) * DEG2RAD for c in ("heading_deg", "pitch_deg", "roll_deg")]
            dC = np.asarray(t["C_hor_from_sensor"]).T @ C_hor_from_deck(*est) @ C_ds
            ang = math.acos(max(-1.0, min(1.0, (np.trace(dC) - 1.0) / 2.0))) * RAD2ASEC
            out["max_single_err"] = max(out["max_single_err"], ang)
            out["n_over"] += int(ang > WRONG_ARCSEC)
            sig = math.sqrt(sum(float(r[c]) ** 2 for c in ("sigma_heading_arcsec", "sigma_pitch_arcsec",
                                                           "sigma_roll_arcsec")))
            out["n_wrong"] += int(ang > WRONG_ARCSEC and ang > WRONG_SIGMAS * sig)
    out["n_eligible"], out["n_eligible_solved"] = n_el, n_el_solved
    # clock and flexure, estimated against true
    params = {}
    cj = d / "conditions.json"
    if cj.exists():
        params = json.loads(cj.read_text()).get("parameters", {})
    clock_true = float(((params.get("clock") or {}).get("A2") or {}).get("offset_s", 0.0))
    wave = ((params.get("flexure") or {}).get("A2") or {}).get("wave_arcsec", [0.0, 0.0, 0.0])
    t_off = (summary.get("time_offsets_s") or {}).get("A2") or {}
    flex = (summary.get("flexure") or {}).get("A2") or {}
    out["clock"] = (t_off.get("offset_s"), t_off.get("sigma_s"), t_off.get("applied"), clock_true)
    amp = (flex.get("wave_amplitude_arcsec") or {}).get("bow")
    amp_sig = (flex.get("wave_amplitude_sigma_arcsec") or {}).get("bow")
    out["flexure"] = (amp, amp_sig, flex.get("applied"), float(wave[0]))
    out["seeing"] = {n: (summary.get("seeing") or {}).get(n, {}).get("noise_floor_arcsec")
                     for n in summary["sensors"]}
    return out


# -- printing ---------------------------------------------------------------------------------
def _f(x, fmt=".2f", none="-"):
    return none if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, fmt)


def availability_text(ev) -> str:
    parts = []
    for name, b in ev["sensors"].items():
        lost = [f"{b[k]} {lab}" for k, lab in (("n_clouded", "clouded"), ("n_moon_in_field", "moon"),
                                                ("n_sun_in_field", "sun"), ("n_failed", "failed")) if b.get(k)]
        parts.append(f"{name} {b['n_solved']}/{b['n_frames']}" + (f" ({', '.join(lost)})" if lost else ""))
    return "; ".join(parts)


def print_table(results: dict, warmup_s: float) -> None:
    print(f"\njoint RMS and RMS(error/sigma) over epochs at t >= {warmup_s:g} s (after the estimators' warm-up); "
          f"availability, eligible frames and wrong solutions over the whole session")
    hdr = (f"{'session':13s} {'availability (solved/frames, lost)':48s} {'eligible':>9s} {'wrong/over':>10s} "
           f"{'joint RMS h/p/r (arcsec)':>24s} {'RMS(err/sig) h/p/r':>19s} {'clock A2 est (true) ms':>27s} "
           f"{'flexure bow amp (true)':>24s}")
    print(hdr)
    print("-" * len(hdr))
    for case, ev in results.items():
        if "error" in ev:
            print(f"{case:13s} ERROR: {ev['error']}")
            continue
        off, sig, app, ctrue = ev["clock"]
        ms = [None if x is None else x * 1e3 for x in (off, sig)]
        clock = (f"{_f(ms[0], '.3f')} +- {_f(ms[1], '.3f')}"
                 f"{'*' if app else ' '} ({ctrue * 1e3:.1f})")
        amp, asig, fapp, ftrue = ev["flexure"]
        flex = f"{_f(amp, '.1f')} +- {_f(asig, '.1f')}{'*' if fapp else ' '} ({ftrue:.0f})"
        print(f"{case:13s} {availability_text(ev):48s} {ev['n_eligible_solved']:4d}/{ev['n_eligible']:<4d} "
              f"{ev['n_wrong']:5d}/{ev['n_over']:<4d} {' / '.join(_f(x) for x in ev['joint_rms']):>24s} "
              f"{' / '.join(_f(x) for x in ev['z_rms']):>19s} {clock:>27s} {flex:>24s}")
    print("(* = applied by the pipeline; '-' = no estimate)")
    late = [(c, ev) for c, ev in results.items() if "error" not in ev]
    if late:
        print(f"joint RMS h/p/r and RMS(error/sigma) from t >= {late[0][1]['late_s']:g} s: " + "; ".join(
            f"{c} {' / '.join(_f(x) for x in ev['joint_rms_late'])} ({' / '.join(_f(x) for x in ev['z_rms_late'])})"
            for c, ev in late))
    seeing = {c: ev["seeing"] for c, ev in results.items()
              if "seeing" in ev and any(v is not None for v in ev["seeing"].values())}
    if seeing:
        print("seeing estimate (noise floor, arcsec): " + "; ".join(
            f"{c} " + " ".join(f"{n} {_f(v)}" for n, v in s.items()) for c, s in seeing.items()))


def check_targets(ev) -> list:
    """(target, value, PASS/FAIL) of the issue's acceptance under realistic.toml."""
    off, _, _, ctrue = ev["clock"]
    amp, _, _, ftrue = ev["flexure"]
    z = ev["z_rms"]
    rows = [
        ("no wrong solution (> 60'' and > 5 sigma)", f"{ev['n_wrong']} wrong; {ev['n_over']} frames beyond 60'' "
         f"(max {ev['max_single_err']:.1f}'')", ev["n_wrong"] == 0),
        (f"every frame with >= {MIN_STARS} stars at SNR >= {SNR_MIN:g} solved",
         f"{ev['n_eligible_solved']} of {ev['n_eligible']}", ev["n_eligible_solved"] == ev["n_eligible"]),
        ("joint RMS <= 1.5'' each angle", " / ".join(_f(x) for x in ev["joint_rms"]) + "''",
         bool(np.all(ev["joint_rms"] <= TARGETS["rms_arcsec"]))),
        ("clock offset within 0.3 ms", f"{_f(None if off is None else off * 1e3, '.3f')} ms (true {ctrue * 1e3:.1f})",
         off is not None and abs(off - ctrue) <= TARGETS["clock_s"]),
        ("flexure amplitude within 20 %", f"{_f(amp, '.2f')}'' (true {ftrue:.0f}'')",
         amp is not None and ftrue > 0 and abs(amp - ftrue) <= TARGETS["flexure_rel"] * ftrue),
        ("RMS(error/sigma) in 0.8-1.25", " / ".join(_f(x) for x in z),
         bool(np.all((z >= TARGETS["z"][0]) & (z <= TARGETS["z"][1])))),
    ]
    return rows


# -- main -------------------------------------------------------------------------------------
def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration-s", type=float, default=16.0, help="session length (s, default 16)")
    ap.add_argument("--realistic-duration-s", type=float, default=120.0,
                    help="length of the realistic and realistic-sky sessions (s, default 120)")
    ap.add_argument("--warmup-s", type=float, default=4.0, help="joint RMS from this time on (s, default 4)")
    ap.add_argument("--only", help="comma-separated subset of " + ",".join(CASES))
    ap.add_argument("--workdir", type=Path, help="render here and keep (default a temporary directory)")
    ap.add_argument("--late-s", type=float, default=8.0, help="also the joint RMS from this time on (s, default 8)")
    ap.add_argument("--reuse", action="store_true", help="reuse sessions already rendered in --workdir")
    ap.add_argument("--windowed-full-frame-every", type=int, default=0, metavar="N",
                    help="measure with windowed tracking, a full frame every N (default 0: every frame whole)")
    ap.add_argument("--evaluate-only", action="store_true",
                    help="with --workdir: evaluate the sessions already measured there (summary.json, attitude.csv)")
    args = ap.parse_args()
    cases = CASES if not args.only else tuple(c.strip() for c in args.only.split(","))
    bad = [c for c in cases if c not in CASES]
    if bad:
        ap.error(f"unknown case(s) {bad}")
    tmp = None
    root = args.workdir
    if root is None:
        tmp = tempfile.TemporaryDirectory(prefix="shipstar-bench-conditions-")
        root = Path(tmp.name)
    root.mkdir(parents=True, exist_ok=True)
    installs = write_installations(root)
    t_all = time.perf_counter()
    results, summaries = {}, {}

    def duration_of(case):
        long = args.realistic_duration_s
        return long if long is not None and case in ("realistic", "realistic-sky") else args.duration_s

    def start_sim(case):
        d = root / case
        if args.reuse and (d / "session.toml").exists():
            import tomllib

            if tomllib.loads((d / "session.toml").read_text())["duration_s"] == duration_of(case):
                return None                      # rendered with this length: reused
        if d.exists():
            import shutil

            shutil.rmtree(d)
        return subprocess.Popen(simulate_cmd(case, d, duration_of(case)), stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True)

    if args.evaluate_only:
        for case in cases:
            d = root / case
            if (d / "summary.json").exists():
                results[case] = evaluate(d, json.loads((d / "summary.json").read_text()), args.warmup_s, args.late_s)
        cases = ()
    sim = start_sim(cases[0]) if cases else None
    for i, case in enumerate(cases):
        t0 = time.perf_counter()
        if sim is not None:
            _, err = sim.communicate()
            if sim.returncode != 0:
                results[case] = {"error": f"simulate-session exit {sim.returncode}: {err.strip()[-300:]}"}
                sim = start_sim(cases[i + 1]) if i + 1 < len(cases) else None
                continue
        t_sim = time.perf_counter() - t0
        d = root / case
        meas = subprocess.Popen(measure_cmd(d, installs, args.windowed_full_frame_every), stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        sim = start_sim(cases[i + 1]) if i + 1 < len(cases) else None        # overlaps the measurement
        t1 = time.perf_counter()
        out, err = meas.communicate()
        t_meas = time.perf_counter() - t1
        if meas.returncode not in (0, 1):
            results[case] = {"error": f"measure exit {meas.returncode}: {err.strip()[-300:]}"}
            continue
        summary = json.loads(out)
        (d / "summary.json").write_text(out)
        summaries[case] = summary
        results[case] = evaluate(d, summary, args.warmup_s, args.late_s)
        print(f"{case:11s} rendered (waited {t_sim:5.1f} s), measured in {t_meas:5.1f} s: "
              f"{availability_text(results[case])}", flush=True)
    lengths = sorted({duration_of(c) for c in results})
    print(f"\n{len(results)} sessions of {' / '.join(f'{x:g}' for x in lengths)} s (2 sensors, 10 frames/s, image level) in "
          f"{time.perf_counter() - t_all:.0f} s")
    print_table(results, args.warmup_s)
    if "realistic" in results and "error" not in results["realistic"]:
        print(f"\nissue 14 targets under realistic.toml ({duration_of('realistic'):g} s session, joint figures after "
              f"{args.warmup_s:g} s):")
        for name, value, ok in check_targets(results["realistic"]):
            print(f"  {'PASS' if ok else 'FAIL'}  {name:50s} {value}")
    if "baseline" in results and "error" not in results["baseline"]:
        print("\nbaseline (no condition): joint RMS " + " / ".join(_f(x) for x in results["baseline"]["joint_rms"])
              + "'' (README, image level: 0.32 / 0.19 / 0.38'' over 60 s with dock-calibrated installations)")
    if tmp is not None:
        tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
