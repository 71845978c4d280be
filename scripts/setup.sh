#!/usr/bin/env bash
# Create or reuse .venv and install the project (CPU torch first). Idempotent:
# a second run with an unchanged pyproject.toml returns in about a second.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    echo "setup: creating .venv" >&2
    "$PY" -m venv .venv
fi
stamp=.venv/.lfd-installed
want=$(sha256sum pyproject.toml scripts/setup.sh | sha256sum | cut -d' ' -f1)
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
    bash scripts/setup_franka.sh   # its own stamp: returns at once when nothing changed
    exit 0
fi
echo "setup: installing CPU torch and the project into .venv (first run takes a few minutes)" >&2
.venv/bin/python -m pip install --quiet --disable-pip-version-check "torch==2.13.0"
.venv/bin/python -m pip install --quiet --disable-pip-version-check -e ".[dev]"
echo "$want" > "$stamp"
bash scripts/setup_franka.sh   # franka-sim in .venv-franka and pylibfranka in .venv (robots/franka.py)
