"""Write the FR3 physics model (MJCF) that the franka-sim server loads through ``$FR3_MJCF``.

franka-sim downloads MuJoCo Menagerie's FR3 on first use; offline it takes any MJCF from
``$FR3_MJCF``. This script makes one from the hand-less ``fr3.urdf`` that franka-sim itself bundles
(and serves to clients through GetRobotModel), so the physics and the kinematics our side loads into
Pinocchio come from one file. Run it with the franka environment's Python (``.venv-franka``, where
franka-sim and its own MuJoCo live); ``scripts/setup_franka.sh`` does.

What it does:

- drops every ``<visual>`` and ``<collision>`` element: they only name meshes, which are not
  installed. Without collision geoms franka-sim's self-collision reflex is off (it says so in its
  log); nothing else it needs depends on geometry;
- keeps every link as a body (``fusestatic="false"``), so the body ``link7`` that franka-sim publishes
  as ``O_T_EE`` and the joints ``joint1`` .. ``joint7`` keep the URDF's names and frames;
- sets the physics parameters of every arm joint to those of MuJoCo Menagerie's ``franka_fr3_v2``, the
  model franka-sim downloads and is tuned against: **armature 0.195 kg m^2, damping 0.003 N m s/rad,
  frictionloss 0.2 N m** (the last two are the URDF's own ``<dynamics>``), MuJoCo's default (Euler)
  integrator, the URDF's inertias. The armature is what matters. franka-sim drives each joint with an
  explicit velocity servo on ``qfrc_applied``, ``tau = KV (dq_cmd - dq)`` with ``KV`` = 450, 450, 350,
  350, 200, 200, 200 N m s/rad, at a 1 kHz physics step; that step is stable only while every
  eigenvalue of ``dt M(q)^-1 KV`` stays below 2. The URDF's bare inertias put the wrist far past that
  (joint 7 turns only its own small link), so without armature the arm drifts and the first motion ends
  in a ``joint_velocity_violation`` reflex. Armature 0.1 is not enough either: joints 1 and 3 are
  coaxial at ``q2 = 0``, their difference mode keeps little more than the two armatures, and the
  largest eigenvalue is about 3.4 at franka-sim's home pose: the servo saturates into a
  sample-to-sample chatter of the measured joint velocities, and the arm creeps while idle. At 0.195
  the largest eigenvalue over the joint range is about 1.9, and measured velocities follow commands
  smoothly;
- compiles the result with MuJoCo to check it, and writes the MJCF (``--out``, default
  ``.venv-franka/fr3.xml`` at the repository root).

Exit status 2, with a one-line message, when franka-sim, MuJoCo or the bundled URDF is missing.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_OUT = ROOT / ".venv-franka" / "fr3.xml"
ARM_JOINTS = tuple(f"joint{i}" for i in range(1, 8))
#: per arm joint, Menagerie's franka_fr3_v2: reflected rotor inertia (kg m^2), viscous damping (N m s/rad),
#: Coulomb friction (N m)
ARMATURE = 0.195
DAMPING = 0.003
FRICTIONLOSS = 0.2


class SetupError(Exception):
    """Something this script needs is missing; the message says what."""


def bundled_urdf() -> Path:
    """The hand-less FR3 URDF inside the installed franka-sim package (``franka_sim/models/fr3.urdf``)."""
    spec = importlib.util.find_spec("franka_sim")   # locates the package without importing it
    if spec is None or not spec.submodule_search_locations:
        raise SetupError(f"franka-sim is not installed in {sys.executable}; run scripts/setup_franka.sh")
    path = Path(list(spec.submodule_search_locations)[0]) / "models" / "fr3.urdf"
    if not path.is_file():
        raise SetupError(f"franka-sim has no bundled URDF at {path}")
    return path


def meshless_urdf(path: Path) -> str:
    """The URDF's text without its visual and collision elements, with MuJoCo's import options added."""
    root = ET.parse(path).getroot()
    for link in root.iter("link"):
        for tag in ("visual", "collision"):
            for element in link.findall(tag):
                link.remove(element)
    for old in root.findall("mujoco"):
        root.remove(old)
    options = ET.SubElement(root, "mujoco")
    ET.SubElement(options, "compiler", {"fusestatic": "false", "discardvisual": "true", "angle": "radian"})
    return ET.tostring(root, encoding="unicode")


def build_mjcf(urdf_text: str) -> str:
    """Compile the URDF with MuJoCo, set the arm joints' physics parameters, and return the MJCF text."""
    try:
        import mujoco
    except ImportError as error:
        raise SetupError(f"MuJoCo is not installed in {sys.executable} ({error})") from error
    spec: Any = mujoco.MjSpec.from_string(urdf_text)
    spec.modelname = "fr3"
    joints = {joint.name: joint for joint in spec.joints}
    missing = [name for name in ARM_JOINTS if name not in joints]
    if missing:
        raise SetupError(f"the bundled URDF lacks the joints {missing}")
    if spec.find_body("link7") is None:
        raise SetupError("the bundled URDF has no body 'link7' (franka-sim's O_T_EE frame)")
    for name in ARM_JOINTS:
        joints[name].armature = ARMATURE
        joints[name].damping = DAMPING
        joints[name].frictionloss = FRICTIONLOSS
    spec.compile()
    return str(spec.to_xml())


def check(mjcf: str) -> None:
    """Load the written MJCF back, as franka-sim will, and check the joints' parameters survived."""
    import mujoco
    import numpy as np

    with tempfile.NamedTemporaryFile("w", suffix=".xml") as f:
        f.write(mjcf)
        f.flush()
        model = mujoco.MjModel.from_xml_path(f.name)
    dofs = [model.jnt_dofadr[model.joint(name).id] for name in ARM_JOINTS]
    if not (np.allclose(model.dof_armature[dofs], ARMATURE) and np.allclose(model.dof_damping[dofs], DAMPING)
            and np.allclose(model.dof_frictionloss[dofs], FRICTIONLOSS)):
        raise SetupError("the written MJCF lost the joints' armature, damping or friction")
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "link7") < 0:
        raise SetupError("the written MJCF has no body 'link7'")


def main(argv: list[str] | None = None) -> int:
    """Write the MJCF; 0 on success, 2 with a message on stderr when something is missing."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"where to write (default {DEFAULT_OUT})")
    args = parser.parse_args(argv)
    try:
        mjcf = build_mjcf(meshless_urdf(bundled_urdf()))
        check(mjcf)
    except SetupError as error:
        print(f"make_fr3_mjcf: {error}", file=sys.stderr)
        return 2
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".tmp")
    tmp.write_text(mjcf, encoding="utf-8")
    tmp.replace(args.out)   # atomic: a reader never sees half a file
    return 0


if __name__ == "__main__":
    sys.exit(main())
