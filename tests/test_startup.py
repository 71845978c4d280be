"""What a command imports: ``lfd train`` loads only what training needs (no plotting, no simulator,
no compiler, no other learner's solver); checked on ``sys.modules`` in a fresh process, not timed."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: never needed to train the tracking learner on positions
NOT_FOR_TRAINING = ("matplotlib", "mujoco", "dm_control", "imageio", "numba", "torchdiffeq", "pinocchio",
                    "scipy.stats", "scipy.integrate", "sim", "robots")


@pytest.mark.parametrize("learner", ["tracking"])
def test_lfd_train_imports_only_what_training_needs(tmp_path: Path, learner: str) -> None:
    out = tmp_path / "m.pt"
    code = ("import sys\n"
            "from lfd.cli import main\n"
            f"code = main(['train', '--learner', '{learner}', '--demos', 'spiral', '--out', {str(out)!r}, '--quiet'])\n"
            "print('EXIT', code)\n"
            f"print('LOADED', *sorted(m for m in {NOT_FOR_TRAINING!r} if m in sys.modules))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    assert "EXIT 0" in proc.stdout and out.stat().st_size > 0
    loaded = next(line for line in proc.stdout.splitlines() if line.startswith("LOADED")).split()[1:]
    assert loaded == [], f"lfd train loaded {loaded}"
