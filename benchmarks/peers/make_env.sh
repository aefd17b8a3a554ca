#!/bin/sh
# Create benchmarks/.peers-venv: the peer star identifiers of benchmarks/bench_identify.py
# (cedar-solve, tetra3rs) in their own environment.
#
# Their pins cannot share shipstar's venv: cedar-solve 0.5 requires Pillow < 9 (shipstar
# needs pillow >= 10) and fails under NumPy 2.  bench_identify.py runs each peer as a
# subprocess of this venv's python (benchmarks/peers/worker.py) and talks to it over a pipe.
#
#   sh benchmarks/peers/make_env.sh            # uses python3 from PATH
#   PYTHON=/usr/bin/python3.11 sh benchmarks/peers/make_env.sh
set -eu
here=$(cd "$(dirname "$0")" && pwd)
venv="$here/../.peers-venv"
py=${PYTHON:-python3}
if [ ! -x "$venv/bin/python" ]; then
    "$py" -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --upgrade pip
"$venv/bin/python" -m pip install --quiet "numpy>=1.26,<2" "tetra3rs>=0.14" "cedar-solve>=0.5"
"$venv/bin/python" - <<'PY'
import numpy, tetra3, tetra3rs
from importlib.metadata import version
print("peers venv ready: numpy", numpy.__version__, "| cedar-solve", version("cedar-solve"),
      "| tetra3rs", version("tetra3rs"))
PY
