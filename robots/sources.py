"""Read one robot file (URDF or MJCF) into both engines: a MuJoCo MjSpec with its mesh assets, and a Pinocchio model.

The URDF goes to MuJoCo's own URDF importer after three rewrites: <visual> elements are dropped (MuJoCo cannot read
their .dae meshes; collision meshes are drawn instead), mesh paths (package://, file://, relative) are resolved to
files whose bytes become named assets, and a <mujoco><compiler/></mujoco> block keeps every link as a body
(fusestatic off) with the file's inertias untouched (inertiafromgeom, balanceinertia off).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin

from robots._mujoco import mujoco
from robots.errors import RobotError

_MESH_FORMATS = (".stl", ".obj", ".msh")
_URDF_COMPILER = {
    "angle": "radian", "fusestatic": "false", "discardvisual": "false", "strippath": "false",
    "inertiafromgeom": "false", "balanceinertia": "false", "autolimits": "true",
}


def source_kind(path: Path) -> str:
    """'urdf' or 'mjcf' from the file name; anything else is a RobotError."""
    suffix = path.suffix.lower()
    if suffix == ".urdf":
        return "urdf"
    if suffix == ".xml":
        return "mjcf"
    raise RobotError(f"unsupported robot file '{path}': expected .urdf or .xml (MJCF)")


def resolve_uri(uri: str, urdf_dir: Path) -> Path:
    """A URDF mesh filename as a file: package://PKG/rest is looked up in the ancestors of the URDF's folder.

    Parameters
    ----------
    uri : str
        The filename as the URDF gives it: ``package://PKG/rest``, ``file://path``, or a path (relative
        to the URDF's folder, or absolute).
    urdf_dir : Path
        The folder of the URDF.

    Returns
    -------
    Path
        The file (not checked to exist, except for ``package://``).

    Raises
    ------
    RobotError
        A ``package://`` file that no ancestor folder holds.
    """
    if uri.startswith("file://"):
        return Path(uri[len("file://"):])
    if uri.startswith("package://"):
        package, _, rest = uri[len("package://"):].partition("/")
        for folder in (urdf_dir, *urdf_dir.parents):
            if folder.name == package and (folder / rest).is_file():
                return folder / rest
            if (folder / package / rest).is_file():
                return folder / package / rest
        raise RobotError(f"mesh '{uri}' not found: no folder '{package}' above {urdf_dir}")
    path = Path(uri)
    return path if path.is_absolute() else urdf_dir / path


def _asset_name(path: Path, assets: dict[str, bytes], taken: dict[Path, str]) -> str:
    """A flat unique asset name for a mesh file, reading its bytes once."""
    path = path.resolve()
    if path in taken:
        return taken[path]
    if not path.is_file():
        raise RobotError(f"mesh file not found: {path}")
    if path.suffix.lower() not in _MESH_FORMATS:
        raise RobotError(f"unsupported mesh format '{path.name}': MuJoCo reads {', '.join(_MESH_FORMATS)}")
    name, k = path.name, 1
    while name in assets:
        name, k = f"{path.stem}_{k}{path.suffix}", k + 1
    assets[name] = path.read_bytes()
    taken[path] = name
    return name


def urdf_spec(path: Path) -> tuple[mujoco.MjSpec, dict[str, bytes]]:
    """MjSpec and mesh assets of a URDF file (visuals dropped, links kept as bodies, inertias as written)."""
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise RobotError(f"cannot parse URDF '{path}': {exc}") from None
    for link in root.iter("link"):
        for visual in link.findall("visual"):
            link.remove(visual)
    assets: dict[str, bytes] = {}
    taken: dict[Path, str] = {}
    for mesh in root.iter("mesh"):
        mesh.set("filename", _asset_name(resolve_uri(mesh.get("filename", ""), path.parent), assets, taken))
    for old in root.findall("mujoco"):
        root.remove(old)
    block = ET.Element("mujoco")
    ET.SubElement(block, "compiler", _URDF_COMPILER)
    root.insert(0, block)
    try:
        spec = mujoco.MjSpec.from_string(ET.tostring(root, encoding="unicode"), assets=assets)
    except ValueError as exc:
        raise RobotError(f"MuJoCo cannot read URDF '{path}': {exc}") from None
    return spec, assets


def mjcf_spec(path: Path) -> tuple[mujoco.MjSpec, dict[str, bytes]]:
    """MjSpec of an MJCF file with its mesh/texture files turned into flat named assets."""
    try:
        spec = mujoco.MjSpec.from_file(str(path))
    except ValueError as exc:
        raise RobotError(f"MuJoCo cannot read MJCF '{path}': {exc}") from None
    assets: dict[str, bytes] = {}
    taken: dict[Path, str] = {}
    for mesh in spec.meshes:
        if mesh.file:
            mesh.file = _asset_name(path.parent / (spec.meshdir or "") / mesh.file, assets, taken)
    for texture in spec.textures:
        if texture.file:
            file = (path.parent / (spec.texturedir or "") / texture.file).resolve()
            if not file.is_file():
                raise RobotError(f"texture file not found: {file}")
            texture.file = file.name
            assets[file.name] = file.read_bytes()
    spec.meshdir = ""
    spec.texturedir = ""
    spec.assets = dict(assets)
    return spec, assets


def pinocchio_model(path: Path, kind: str, locked: dict[str, float]) -> pin.Model:
    """Pinocchio model of the file with the ``locked`` joints (name -> value) fixed; the rest must be 1-DoF joints."""
    try:
        model = pin.buildModelFromUrdf(str(path)) if kind == "urdf" else pin.buildModelFromMJCF(str(path))
    except (ValueError, RuntimeError) as exc:
        message = str(exc).strip().splitlines()[-1]
        raise RobotError(f"Pinocchio cannot read '{path}': {message}") from None
    unknown = sorted(set(locked) - set(model.names))
    if unknown:
        raise RobotError(f"cannot lock unknown joints {unknown} of '{path}'")
    q_ref = pin.neutral(model)
    lock_ids = []
    for name, value in locked.items():
        jid = model.getJointId(name)
        q_ref[model.joints[jid].idx_q] = value
        lock_ids.append(jid)
    if lock_ids:
        model = pin.buildReducedModel(model, lock_ids, q_ref)
    for jid in range(1, model.njoints):
        joint = model.joints[jid]
        if joint.nq != 1 or joint.nv != 1:
            raise RobotError(f"joint '{model.names[jid]}' of '{path}' is a {joint.shortname()}: arm joints must be "
                             "1-DoF revolute or prismatic with limits")
    if model.nq == 0:
        raise RobotError(f"'{path}' has no movable joints")
    return model


def lock_mujoco_joints(spec: mujoco.MjSpec, locked: dict[str, float]) -> None:
    """Remove each locked slide joint from the spec, moving its body by value * axis (as Pinocchio's reduced model).
    Joint couplings on them must be dropped first (drop_joint_couplings)."""
    for name, value in locked.items():
        joint = spec.joint(name)
        if joint is None:
            raise RobotError(f"MuJoCo model has no joint '{name}' to lock")
        if joint.type != mujoco.mjtJoint.mjJNT_SLIDE:
            raise RobotError(f"cannot lock joint '{name}': only slide joints (gripper fingers) are locked")
        body = joint.parent
        axis = np.asarray(joint.axis, dtype=float) / np.linalg.norm(joint.axis)
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, np.asarray(body.quat, dtype=float))
        body.pos = np.asarray(body.pos) + rot.reshape(3, 3) @ (axis * value)
        spec.delete(joint)


def drop_joint_couplings(spec: mujoco.MjSpec, joints: tuple[str, ...]) -> None:
    """Remove joint equality constraints (e.g. URDF <mimic>) touching ``joints``: Pinocchio treats arm joints as
    independent, and locked joints disappear."""
    names = set(joints)
    for eq in list(spec.equalities):
        if eq.type == mujoco.mjtEq.mjEQ_JOINT and {eq.name1, eq.name2} & names:
            spec.delete(eq)
