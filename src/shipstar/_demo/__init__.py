"""``shipstar demo``: the seeds' story end to end on simulated frames.

1. the dock calibration (seed 000, Jiangyin 2013-03-15) of sensors A1 and A2: frames
   rendered as images, processed by the pipeline, averaged into installation angles;
2. a session at sea, the ship rolling and pitching: each sensor's ship attitude, the
   seeds' fusion rule and the joint solution, with the dock-calibrated installations;
3. a results table against the truth beside the seeds' published figures, and an HTML
   report (``shipstar.report``).

Public API::

    run_demo(out_dir, quick=False, plan=None, config_dir=None, progress=None) -> DemoResult
    results_dict(result) -> dict;  results_text(result) -> str
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

from shipstar._demo._table import results_dict, results_text
from shipstar.errors import ShipstarError

__all__ = ["DemoResult", "DemoPlan", "run_demo", "results_dict", "results_text", "QUICK", "FULL"]


@dataclass(frozen=True)
class DemoPlan:
    """How much of each configured session the demo runs (seconds are capped, never raised).

    Attributes
    ----------
    dock_s, dock_image_s : float
        Dock session length and its image-level part (s).
    sea_s, sea_image_s : float
        Sea session length and its image-level part (s).
    """

    dock_s: float
    dock_image_s: float
    sea_s: float
    sea_image_s: float


#: The full run: every configured second (the demo files: dock 16 s, all images; sea 60 s,
#: the first 30 s images, the rest centroid level).
FULL = DemoPlan(float("inf"), float("inf"), float("inf"), float("inf"))
#: ``--quick``: dock 2 s (images), sea 10 s (the first 1 s images).
QUICK = DemoPlan(2.0, 2.0, 10.0, 1.0)


@dataclass(frozen=True, eq=False)
class DemoResult:
    """What :func:`run_demo` did and found (see :func:`results_dict` for the numbers)."""

    quick: bool
    out_dir: Path
    report_path: Path
    dock_config: object
    sea_config: object
    dock_spec: object
    sea_spec: object
    dock: tuple
    sea: object
    layout: object
    timing_s: dict
    files: dict = field(default_factory=dict)


def _load(config_dir, out_dir: Path):
    from shipstar.config import load_project, write_example_config

    if config_dir is not None:
        return load_project(config_dir), None
    used = out_dir / "config-used"
    write_example_config(used, overwrite=True)
    return load_project(used), used


def _specs(project, plan: DemoPlan):
    dock_cfg, sea_cfg = project.dock, project.sea
    dock_spec = dock_cfg.spec().replace(duration_s=min(dock_cfg.duration_s, plan.dock_s))
    sea_spec = sea_cfg.spec().replace(duration_s=min(sea_cfg.duration_s, plan.sea_s))
    return (dock_spec, min(dock_cfg.simulation.image_level_s, plan.dock_image_s),
            sea_spec, min(sea_cfg.simulation.image_level_s, plan.sea_image_s))


def _databases(spec, bar) -> dict:
    from shipstar.identify import build_database
    from shipstar.sky.catalog import load_hipparcos

    bar.stage("catalog and star databases", len(spec.sensors) + 1)
    load_hipparcos()                      # disk-cached after the first run
    bar.advance()
    out = {}
    for s in spec.sensors:
        out[s.name] = build_database(s.camera)
        bar.advance()
    bar.finish()
    return out


#: What a demo writes into its output folder: an earlier demo's are removed before a new
#: run, so that no old ``config-used/`` or report is left beside the new results.
DEMO_OUTPUTS = ("report.html", "results.json", "config-used", "dock", "sea")
#: The files a demo writes in its ``sea/`` folder (the session's tables); in ``dock/`` it
#: writes ``<sensor>.installation.toml``.
DEMO_SEA_FILES = ("track.csv", "weather.csv", "truth.csv")


def _demo_wrote(folder: str, path: Path) -> bool:
    """A file of the demo's own in its ``sea/`` or ``dock/`` folder."""
    if not path.is_file() or path.is_symlink():
        return False
    return path.name in DEMO_SEA_FILES if folder == "sea" else path.name.endswith(".installation.toml")


def _check_out_folder(out: Path) -> None:
    """Refuse (one line) an output folder whose ``sea/`` or ``dock/`` holds anything but an
    earlier demo's own files: a user's session there (frames, its track) would be
    overwritten or removed."""
    earlier = (out / "results.json").is_file()
    for folder in ("sea", "dock"):
        d = out / folder
        if not (d.exists() or d.is_symlink()):
            continue
        if d.is_symlink() or not d.is_dir():
            raise ShipstarError(f"{d} is in the way of the demo's {folder}/ folder: give another --out")
        others = sorted(p.name for p in d.iterdir() if not _demo_wrote(folder, p))
        if others or not earlier:
            what = (f"holds {', '.join(others[:3])}{' ...' if len(others) > 3 else ''}, which the demo did not "
                    f"write" if others else "is not an earlier demo's (no results.json beside it)")
            raise ShipstarError(f"{d} {what}: give an empty or new --out folder, or an earlier demo's")


def _clean_earlier_demo(out: Path) -> None:
    """Remove an earlier demo's outputs (:data:`DEMO_OUTPUTS`) from ``out``: in ``sea/``
    and ``dock/`` only its own files (:func:`_check_out_folder` has refused any other);
    nothing else in the folder is touched."""
    import shutil

    if not out.is_dir() or not any((out / n).exists() for n in ("results.json", "report.html", "config-used")):
        return
    for name in DEMO_OUTPUTS:
        p = out / name
        if name in ("sea", "dock"):
            if p.is_dir() and not p.is_symlink():
                for f in p.iterdir():
                    if _demo_wrote(name, f):
                        f.unlink()
                if not any(p.iterdir()):
                    p.rmdir()
        elif p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        elif p.exists() or p.is_symlink():
            p.unlink()


def _save_installations(dock, out_dir: Path) -> dict:
    from shipstar.calibrate.installation import save_installation

    files = {}
    for d in dock:
        path = out_dir / "dock" / f"{d.name}.installation.toml"
        save_installation(d.installation, path)
        files[f"installation {d.name}"] = path
    return files


def run_demo(out_dir, *, quick: bool = False, plan: DemoPlan | None = None, config_dir=None,
             progress=None) -> DemoResult:
    """Run the demo and write its report and files into ``out_dir``.

    Parameters
    ----------
    out_dir : str or Path
        Created if needed.  Receives ``report.html``, ``results.json``,
        ``dock/<sensor>.installation.toml``, ``sea/{track,weather,truth}.csv`` and (without
        ``config_dir``) ``config-used/``, the demo's configuration.
    quick : bool
        The short run (:data:`QUICK`) instead of the full one (:data:`FULL`).
    plan : DemoPlan, optional
        Another length (overrides ``quick``; e.g. tests).
    config_dir : str or Path, optional
        A directory written by ``shipstar demo --write-config`` (and edited).
    progress : shipstar._demo._progress.Progress, optional
        Default: a progress bar on stderr.

    Returns
    -------
    DemoResult
    """
    import json

    from shipstar._demo._dock import run_dock
    from shipstar._demo._layout import layout_sweep
    from shipstar._demo._progress import Progress
    from shipstar._demo._report import write_demo_report
    from shipstar._demo._sea import run_sea

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ShipstarError(f"output {out} exists and is not a directory")
    _check_out_folder(out)
    _clean_earlier_demo(out)
    bar = Progress() if progress is None else progress
    timing = {}
    t0 = time.perf_counter()
    project, used = _load(config_dir, out)
    if plan is None:
        plan = QUICK if quick else FULL
    elif not isinstance(plan, DemoPlan):
        raise ShipstarError(f"plan must be a DemoPlan, got {type(plan).__name__}")
    dock_spec, dock_img, sea_spec, sea_img = _specs(project, plan)
    databases = _databases(dock_spec, bar)
    timing["setup"] = time.perf_counter() - t0
    t = time.perf_counter()
    bar.stage("dock calibration (frames)", sum(len(dock_spec.times_s(s)) for s in dock_spec.sensors))
    dock = run_dock(project.dock, dock_spec, dock_img, bar, databases)
    bar.finish()
    timing["dock"] = time.perf_counter() - t
    t = time.perf_counter()
    bar.stage("at sea (frames)", sum(len(sea_spec.times_s(s)) for s in sea_spec.sensors))
    sea = run_sea(project.sea, sea_spec, {d.name: d.installation for d in dock}, sea_img, out / "sea", bar, databases)
    bar.finish()
    timing["sea"] = time.perf_counter() - t
    t = time.perf_counter()
    bar.stage("report", 1)
    layout = layout_sweep(sea_spec, dock, sea)
    files = {"report": out / "report.html", "results": out / "results.json", **_save_installations(dock, out),
             **{f"sea {k}": v for k, v in sea.files.items()}}
    if used is not None:
        files["configuration"] = used
    result = DemoResult(quick, out, out / "report.html", project.dock, project.sea, dock_spec, sea_spec, dock, sea,
                        layout, timing, files)
    write_demo_report(result, databases, result.report_path)
    bar.finish()
    timing["report"] = time.perf_counter() - t
    from shipstar._atomic import atomic_write_text

    atomic_write_text(out / "results.json", json.dumps(results_dict(result), indent=1) + "\n")
    return result
