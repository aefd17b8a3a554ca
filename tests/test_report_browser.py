"""The demo's report looked at in a real browser: headless Chromium (Debian's package).

The report carries a small inline script that, after the page has loaded, writes a JSON
verdict into ``<pre id="shipstar-verdict">``: how many images there are, how many
decoded, and anything that reached ``window.onerror`` or ``console.error``.  Chromium's
``--dump-dom`` prints the DOM after the load, so the verdict can be read without a
WebDriver.  A control page with a broken image and a script error proves the check
can fail.

Chromium is installed by the session fixture when it is missing and the tests run as
root (CI on a fresh machine); otherwise the tests FAIL with the command to run.
"""

from __future__ import annotations

import html
import io
import json
import os
import re
import shutil
import subprocess

import numpy as np
import pytest

CHROMIUM = "/usr/bin/chromium"
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--hide-scrollbars")


def _install_chromium() -> str:
    """Install Debian's chromium with apt-get; returns '' on success, else why not."""
    if not hasattr(os, "geteuid") or os.geteuid() != 0:
        return "not root"
    if shutil.which("apt-get") is None:
        return "no apt-get"
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    for cmd in (["apt-get", "update", "-qq"], ["apt-get", "install", "-y", "-qq", "chromium"]):
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=1800)
        if proc.returncode != 0:
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["?"]
            return f"{' '.join(cmd)} failed: {tail[0]}"
    return ""


@pytest.fixture(scope="session")
def chromium():
    if not os.path.exists(CHROMIUM):
        why = _install_chromium()
        if why or not os.path.exists(CHROMIUM):
            pytest.fail(f"headless Chromium is needed at {CHROMIUM} and could not be installed ({why or 'missing'}); "
                        "run as root: apt-get update && apt-get install -y chromium")
    return CHROMIUM


def _chromium(binary, tmp_path, *args, timeout=180) -> subprocess.CompletedProcess:
    profile = tmp_path / f"profile-{len(list(tmp_path.glob('profile-*')))}"
    return subprocess.run([binary, *FLAGS, f"--user-data-dir={profile}", *args], capture_output=True, text=True,
                          timeout=timeout)


def _verdict(binary, tmp_path, page) -> dict:
    proc = _chromium(binary, tmp_path, "--virtual-time-budget=10000", "--dump-dom", page.resolve().as_uri())
    assert proc.returncode == 0, proc.stderr[-2000:]
    m = re.search(r'<pre id="shipstar-verdict" hidden="">(.*?)</pre>', proc.stdout, re.S)
    assert m is not None, "no verdict element in the dumped DOM"
    assert m.group(1).strip(), "the verdict is empty: the page's load handler did not run"
    return json.loads(html.unescape(m.group(1)))


@pytest.fixture(scope="module")
def demo_report(tmp_path_factory):
    """A short demo run (same report, fewer frames than --quick)."""
    from shipstar._demo import DemoPlan, run_demo
    from shipstar._demo._progress import Progress

    out = tmp_path_factory.mktemp("demo")
    result = run_demo(out, plan=DemoPlan(1.0, 1.0, 4.0, 0.5), progress=Progress(enabled=False))
    return result.report_path


def test_demo_report_loads_every_image_without_errors(chromium, demo_report, tmp_path):
    n_img = demo_report.read_text(encoding="utf-8").count("<img ")
    assert n_img == 6
    verdict = _verdict(chromium, tmp_path, demo_report)
    assert verdict == {"n_images": n_img, "n_loaded": n_img, "not_loaded": [], "errors": []}


def test_demo_report_screenshot_is_a_rendered_page(chromium, demo_report, tmp_path):
    from PIL import Image

    shot = tmp_path / "report.png"
    proc = _chromium(chromium, tmp_path, "--window-size=1200,2400", f"--screenshot={shot}",
                     demo_report.resolve().as_uri())
    assert proc.returncode == 0 and shot.is_file(), proc.stderr[-2000:]
    with Image.open(shot) as im:
        rgb = np.asarray(im.convert("RGB"), float)
    assert rgb.shape == (2400, 1200, 3)
    # text, tables and plots: many distinct tones, and the frame plots' dark pixels
    assert rgb.std() > 30.0
    assert np.mean(rgb.sum(axis=2) < 100) > 0.02


def test_the_check_catches_a_broken_image_and_a_script_error(chromium, tmp_path):
    from PIL import Image

    from shipstar.report import Report

    buf = io.BytesIO()
    Image.new("RGB", (4, 4), (0, 0, 0)).save(buf, format="PNG")
    rep = Report("control")
    rep.figure(buf.getvalue(), "good", "good image")
    rep.figure(buf.getvalue(), "bad", "bad image")
    text = rep.to_html()
    head, sep, tail = text.rpartition('src="data:image/png;base64,')      # the second image: corrupt it
    text = head + sep + "iVBORw0KGgoAAAAAbm90IGEgcG5n" + tail[tail.index('"'):]
    text = text.replace("</main>", "<script>undefined_function_of_the_control_page();</script>"
                                   "<script>console.error('logged by the control page');</script></main>")
    page = tmp_path / "control.html"
    page.write_text(text, encoding="utf-8")
    v = _verdict(chromium, tmp_path, page)
    assert (v["n_images"], v["n_loaded"], v["not_loaded"]) == (2, 1, ["bad image"])
    assert any("undefined_function_of_the_control_page" in e for e in v["errors"]), v
    assert any("logged by the control page" in e for e in v["errors"]), v
