"""The wheel is a product: built from a copy of the sources, installed (no dependencies) into a
fresh virtual environment that does not see the checkout, it runs ``lfd --help``, places the
spiral on the planar arm and loads the Panda, from a folder outside the checkout.

The fresh environment (``python -m venv --without-pip``) finds the dependencies through a ``.pth``
file listing this environment's package folders as plain paths: a plain path line adds the folder
without running the ``.pth`` files inside it, so the editable install of this checkout stays out.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("pyproject.toml", "README.md", "lfd", "robots", "sim", "assets")

pytestmark = pytest.mark.slow

_PLANAR_RUN = """
import sys
import lfd, robots, sim
from robots import load_robot
for m in (lfd, robots, sim):
    assert m.__file__.startswith(sys.prefix), (m.__name__, m.__file__)
robot = load_robot("planar")
demos = lfd.load_demos("spiral")
exp = sim.Experiment(robot, demos)
print("planar", robot.mj_model.nq, robot.name, exp.placement is not None)
pour = lfd.load_demos("robottasks:pouring")   # RoboTasks9, shipped inside the wheel
assert pour.has_orientation and pour.x.shape == (9, 1000, 3)
panda = load_robot("panda")   # example-robot-data's files, the meshes from the user's cache
print("panda", panda.name, len(panda.arm_joints))
"""


def _dependency_paths(root: Path) -> list[str]:
    """This interpreter's import folders that hold the dependencies: sys.path from a neutral cwd,
    without the checkout (the editable install maps it through a finder, left out) and the
    standard library (the fresh environment has its own)."""
    out = subprocess.run([sys.executable, "-c", "import sys; print('\\n'.join(sys.path))"], capture_output=True,
                         text=True, cwd=root, check=True, env={k: v for k, v in os.environ.items()
                                                               if k != "PYTHONPATH"}).stdout.splitlines()
    stdlib = {sysconfig.get_paths()[k] for k in ("stdlib", "platstdlib")}
    keep = []
    for p in out:
        if not p or p in stdlib or p.endswith(".zip") or "lib-dynload" in p:
            continue
        if Path(p).resolve() == ROOT or (ROOT in Path(p).resolve().parents and ".venv" not in Path(p).parts):
            continue
        keep.append(p)
    return keep


def test_wheel_installs_and_runs_without_the_checkout(tmp_path: Path) -> None:
    src = tmp_path / "src"
    src.mkdir()
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
    for name in SOURCES:
        p = ROOT / name
        if p.is_dir():
            shutil.copytree(p, src / name, symlinks=True, ignore=ignore)
        else:
            shutil.copy2(p, src / name)
    dist = tmp_path / "dist"
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                        "-w", str(dist), str(src)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    (wheel,) = dist.glob("lfd_arm-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert "robots/assets/planar_arm.xml" in names
    assert {"lfd/assets/robottasks/pouring.npy", "lfd/assets/robottasks/LICENSE",
            "lfd/assets/robottasks/README.md"} <= set(names)
    assert not any(n.startswith("robots/assets/robottasks") for n in names)       # one copy of the data
    assert {"lfd/py.typed", "robots/py.typed", "sim/py.typed"} <= set(names)

    env_dir = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(env_dir)], check=True)
    python = env_dir / "bin" / "python"
    purelib = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             capture_output=True, text=True, check=True).stdout.strip()
    Path(purelib, "lfd-test-dependencies.pth").write_text("\n".join(_dependency_paths(tmp_path)) + "\n")
    r = subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "-q",
                        "--no-index", str(wheel)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr

    run = tmp_path / "elsewhere"
    run.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["LFD_CACHE_DIR"] = str(run / "models")
    r = subprocess.run([str(env_dir / "bin" / "lfd"), "--help"], capture_output=True, text=True, cwd=run, env=env)
    assert r.returncode == 0 and r.stdout.startswith("usage: lfd"), r.stderr
    r = subprocess.run([str(python), "-c", _PLANAR_RUN], capture_output=True, text=True, cwd=run, env=env,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[-2:] == ["planar 3 planar True", "panda panda 7"]
