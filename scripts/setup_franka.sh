#!/usr/bin/env bash
# Create or reuse .venv-franka, the environment of the franka-sim server (it pins its own numpy and
# MuJoCo, so it cannot share .venv), make its FR3 physics model .venv-franka/fr3.xml
# (scripts/make_fr3_mjcf.py), and install pylibfranka, libfranka's Python client, into .venv.
# Run by scripts/setup.sh after the main install; needs .venv. Idempotent: a second run with
# unchanged scripts returns at once. Progress goes to stderr.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
FRANKA_SIM="franka-sim==1.1.7"
PYLIBFRANKA="pylibfranka==0.21.3"
if [ ! -x .venv/bin/python ]; then
    echo "setup_franka: no .venv here; run scripts/setup.sh first" >&2
    exit 1
fi
stamp=.venv-franka/.lfd-franka-installed
want=$(cat scripts/setup_franka.sh scripts/make_fr3_mjcf.py | sha256sum | cut -d' ' -f1)
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && [ -f .venv-franka/fr3.xml ] \
        && compgen -G ".venv/lib/python3*/site-packages/pylibfranka/__init__.py" > /dev/null; then
    exit 0
fi
if [ ! -x .venv-franka/bin/python ]; then
    echo "setup_franka: creating .venv-franka" >&2
    "$PY" -m venv .venv-franka
fi
# optional: where a wheel is missing (pylibfranka has none for Python 3.13 or glibc < 2.34) the rest of
# the project works, the libfranka tests skip (and fail under CI), and the next set-up tries again
skip() {
    echo "setup_franka: $1; robots.franka and its tests are unavailable here" >&2
    exit 0
}
echo "setup_franka: installing $FRANKA_SIM into .venv-franka and $PYLIBFRANKA into .venv" >&2
.venv-franka/bin/python -m pip install --quiet --disable-pip-version-check "$FRANKA_SIM" \
    || skip "$FRANKA_SIM did not install into .venv-franka"
.venv-franka/bin/python scripts/make_fr3_mjcf.py --out .venv-franka/fr3.xml || skip "the FR3 model was not made"
# pylibfranka needs only numpy>=1.19, which .venv has: nothing of .venv is changed but this one package
.venv/bin/python -m pip install --quiet --disable-pip-version-check "$PYLIBFRANKA" \
    || skip "$PYLIBFRANKA has no wheel for this Python or system"
.venv/bin/python -c "import pylibfranka" || skip "pylibfranka does not import in .venv"
echo "$want" > "$stamp"
