"""The identity of the shipstar code a process runs (``shipstar._codeid``), which the
archive's tasks compare with the command's: its tree digest against copies of the package
changed in one way each, and the compiled modules' source digests against the checkout's
C sources (a kernel built from other sources fails here)."""

import hashlib
import re
import shutil
from dataclasses import replace
from pathlib import Path

import pytest

import shipstar
from shipstar._codeid import COMPILED_MODULES, code_identity, environment, tree_digest
from shipstar.errors import ShipstarError

CHECKOUT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def package_copy(tmp_path_factory):
    """A copy of the package's directory (with whatever it holds: caches, built modules)."""
    dest = tmp_path_factory.mktemp("codeid") / "shipstar"
    shutil.copytree(Path(shipstar.__file__).parent, dest)
    return dest


def _independent_digest(root: Path) -> str:
    """The documented rule written out again: *.py anywhere and every file under data/,
    no __pycache__, in path order, path and length and bytes."""
    h = hashlib.sha256()
    names = []
    for p in root.rglob("*"):
        rel = p.relative_to(root).as_posix()
        if p.is_file() and "__pycache__" not in rel.split("/") and (rel.endswith(".py") or rel.startswith("data/")):
            names.append(rel)
    for rel in sorted(names):
        data = (root / rel).read_bytes()
        h.update(rel.encode() + b"\0" + str(len(data)).encode() + b"\0" + data)
    return h.hexdigest()


def test_tree_digest_counts_sources_and_data_only(package_copy, tmp_path):
    root = tmp_path / "shipstar"
    shutil.copytree(package_copy, root)
    base = tree_digest(root)
    assert base == tree_digest(package_copy) == _independent_digest(root)
    (root / "__pycache__").mkdir(exist_ok=True)
    (root / "__pycache__" / "frames.cpython-311.pyc").write_bytes(b"\0" * 64)
    (root / "_cfits.so").write_bytes(b"built elsewhere")             # compiled modules: by their sources
    (root / "live" / "console" / "extra.css").write_text("body {}")   # not data the rows use
    assert tree_digest(root) == base
    frames = root / "frames.py"
    text = frames.read_bytes()
    frames.write_bytes(text + b"\n")                                  # one byte more in one module
    assert tree_digest(root) != base
    frames.write_bytes(text)
    assert tree_digest(root) == base
    (root / "frames.py").rename(root / "frames2.py")                  # the same bytes under another name
    assert tree_digest(root) != base
    (root / "frames2.py").rename(root / "frames.py")
    camera = next((root / "data" / "cameras").glob("*.toml"))
    camera.write_text(camera.read_text().replace("=", " = ", 1))      # a data file
    assert tree_digest(root) != base


@pytest.mark.parametrize("name", COMPILED_MODULES)
def test_compiled_modules_carry_their_sources_digest(name):
    """Each kernel was built from the checkout's C sources (setup.py: path, length, bytes of
    the source, then of the headers it includes: the digest's export, QUEST)."""
    import importlib

    setup_py = (CHECKOUT / "setup.py").read_text()
    module = importlib.import_module(name)
    source = "src/" + name.replace(".", "/") + ".c"
    files = [source, "src/shipstar/_csource.h"] + (["src/shipstar/_cquest.h"] if name.endswith(
        ("identify._ckernels", "attitude._ckernels")) else [])
    assert all(f in setup_py for f in files)
    h = hashlib.sha256()
    for f in files:
        data = (CHECKOUT / f).read_bytes()
        h.update(f"{f}\0{len(data)}\0".encode() + data)
    assert module.SOURCE_SHA256 == h.hexdigest()


def test_code_identity_is_the_version_and_a_digest():
    version, digest = code_identity().split(":")
    assert version == shipstar.__version__ and len(digest) == 64 and code_identity() == code_identity()


def test_a_task_on_other_code_refuses(monkeypatch):
    """use_job_tables (every task's start) with a job made by other code: a one-line error;
    the same code, or a job that does not say (measure's own forked pool), passes."""
    import shipstar._codeid
    from shipstar.pipeline._measure import MeasureJob, use_job_tables

    job = MeasureJob((), None, None, None, (0.0, 0.0), code_identity=code_identity())
    use_job_tables(job)
    use_job_tables(replace(job, code_identity=""))
    with pytest.raises(ShipstarError, match="this worker runs other shipstar code") as err:
        use_job_tables(replace(job, code_identity=shipstar.__version__ + ":" + "0" * 64))
    assert "\n" not in str(err.value)
    monkeypatch.setattr(shipstar._codeid, "code_identity", lambda: "0.0.9:" + "1" * 64)   # this process, edited
    with pytest.raises(ShipstarError, match=r"\(0\.0\.9:1{16}\) than the command \(0\.1\.0:"):
        use_job_tables(job)


def test_environment_names_the_versions_of_this_process():
    """Against the modules' own version attributes, gathered independently."""
    import platform
    import sys

    import erfa
    import numpy

    env = environment()
    assert f"python {sys.version_info.major}.{sys.version_info.minor}.{sys.version_info.micro} " in env
    assert f"numpy {numpy.__version__};" in env and f"pyerfa {erfa.__version__} " in env
    assert erfa.version.erfa_version in env and env.endswith(platform.machine())


def test_a_task_in_another_environment_refuses():
    """A worker with other versions (another NumPy: other rounding in places) refuses with
    both environments in one line."""
    from shipstar.pipeline._measure import MeasureJob, use_job_tables

    job = MeasureJob((), None, None, None, (0.0, 0.0), environment=environment())
    use_job_tables(job)
    other = environment().replace("numpy ", "numpy 0.")
    with pytest.raises(ShipstarError, match="this worker's environment .* is not the command's") as err:
        use_job_tables(replace(job, environment=other))
    assert "\n" not in str(err.value) and other in str(err.value)


def test_a_resume_after_the_code_changed_is_refused(monkeypatch):
    """The resume fingerprint holds this process's code identity (measure and the archive
    alike): a stopped run continued by other code would mix two versions' rows."""
    import shipstar._codeid
    from shipstar.pipeline._measure import MeasureJob, _fingerprint

    job = MeasureJob((), None, None, None, (0.0, 0.0))
    assert _fingerprint(job, [], 30.0)["code_identity"] == code_identity()
    assert _fingerprint(job, [], 30.0)["environment"] == environment()
    monkeypatch.setattr(shipstar._codeid, "code_identity", lambda: "edited")
    assert _fingerprint(job, [], 30.0)["code_identity"] == "edited"


def test_a_resume_refusal_after_an_upgrade_says_so(tmp_path):
    """The checkpoint of a run made by other code: the refusal names the code, not "other
    input"; other data as well is still "other input"."""
    import json

    from shipstar.pipeline._measure import RESUME_VERSION, _read_checkpoint

    partial = tmp_path / "att.csv.partial"
    partial.write_text("# header\n")
    now = {"n_frames": [10], "code_identity": code_identity(), "environment": environment()}
    for then, message in (({**now, "code_identity": "0.0.9:" + "1" * 64}, "written by other shipstar code or another "
                           "environment (code_identity differ): one file does not mix two versions' rows"),
                          ({**now, "environment": "python 3.9"}, "(environment differ)"),
                          ({**now, "n_frames": [9], "code_identity": "x"},
                           "written by a run with other input (code_identity, n_frames differ)")):
        checkpoint = tmp_path / "att.csv.resume"
        checkpoint.write_text(json.dumps({"version": RESUME_VERSION, "fingerprint": then, "bytes": 9}))
        with pytest.raises(ShipstarError, match=re.escape(message)) as err:
            _read_checkpoint(checkpoint, now, partial)
        assert "\n" not in str(err.value)
