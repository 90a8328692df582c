#!/usr/bin/env bash
# Create (or refresh) the project's virtual environment .venv with the pinned ROS 2 Jazzy
# wheels and the Python dependencies, and install this package into it (editable).
# Idempotent: a second run only checks. Needs Python 3.11 (the Jazzy wheels are built for it).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-}
if [ -z "$PY" ]; then
  if command -v python3.11 >/dev/null 2>&1; then PY=python3.11; else PY=python3; fi
fi
if ! "$PY" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
  echo "setup_venv.sh: the ROS 2 Jazzy wheels need Python 3.11; $PY is $("$PY" -V 2>&1)." >&2
  echo "Set PYTHON=/path/to/python3.11, or use a ROS 2 Jazzy install with colcon (README)." >&2
  exit 1
fi
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
stamp=.venv/.installed-$(cat requirements.txt setup.py | sha1sum | cut -c1-12)
if [ ! -f "$stamp" ]; then
  .venv/bin/python -m pip install --quiet --upgrade pip
  .venv/bin/python -m pip install --quiet -r requirements.txt
  .venv/bin/python -m pip install --quiet --no-deps -e .
  # Fill numba's cache once, so the node's first start already runs compiled. Not required:
  # a node with an empty cache answers on the numpy path while it compiles in the background.
  echo "setup_venv.sh: compiling the optional numba kernels once (about a minute on two cores)..." >&2
  .venv/bin/python -c 'import time; start = time.perf_counter()
from obstacle_detection.pipeline import Detector
from obstacle_detection.ros import rvl
Detector().warm_up(); rvl.warm_up()
print(f"setup_venv.sh: numba kernels ready in {time.perf_counter() - start:.1f} s")' >&2 \
    || echo "setup_venv.sh: warning: compiling the numba kernels failed; the node will" \
            "run on the numpy path (same results, slower)" >&2
  rm -f .venv/.installed-*
  touch "$stamp"
fi
echo "setup_venv.sh: .venv ready ($(.venv/bin/python -V))" >&2
