"""Visual geometry of a URDF arm for rendering: its <visual> meshes as non-colliding MuJoCo geoms.

MuJoCo reads STL and OBJ meshes only; COLLADA (.dae) visual meshes, as example-robot-data ships
the Panda's, are converted once with trimesh (and pycollada) into binary STL parts, one part per
colour of the source (its materials' base colours), and kept in a user cache folder
(``cache_dir``), keyed by the sha256 of the source file, checksummed and written atomically
(``convert_mesh``): a damaged cache file is converted again with one warning. Nothing is copied
into the repository and nothing is fetched from the network.

Visual geoms: group ``VISUAL_GROUP`` (2), contype = conaffinity = 0, no mass (the scene compiles
with ``inertiafromgeom`` off). When a link has a readable visual, its collision geoms move to
``COLLISION_GROUP`` (3, hidden in renders by default) and keep colliding. A link whose visuals
cannot be read (missing file, unknown format, no trimesh) keeps its collision geoms visible, each
link in its own colour from ``LINK_PALETTE``.
"""

from __future__ import annotations

import hashlib
import io
import os
import tempfile
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np

from robots._mujoco import mujoco

VISUAL_GROUP = 2
COLLISION_GROUP = 3
CONVERTER_VERSION = "4"   # part of the cache key: bump when the conversion or the cache file changes
CLUSTER_CELL_M = 0.008    # vertex-clustering grid of the converted meshes (see ``simplify``)
DIRECT_FORMATS = (".stl", ".obj")
_RGBA = tuple[float, float, float, float]   # for typing.cast
LINK_PALETTE: tuple[tuple[float, float, float, float], ...] = (
    (0.85, 0.86, 0.88, 1.0), (0.26, 0.45, 0.75, 1.0), (0.90, 0.62, 0.20, 1.0), (0.35, 0.65, 0.45, 1.0),
    (0.70, 0.35, 0.55, 1.0), (0.45, 0.45, 0.48, 1.0), (0.55, 0.75, 0.85, 1.0), (0.80, 0.45, 0.35, 1.0),
)


@dataclass
class VisualReport:
    """What ``add_visuals`` did: links drawn with visual geoms, links drawn with coloured collision
    geoms (``fallback``, link -> reason) and the number of mesh parts added."""

    visual_links: list[str] = field(default_factory=list)
    fallback: dict[str, str] = field(default_factory=dict)
    parts: int = 0


def cache_dir() -> Path:
    """The converted-mesh cache: ``$LFD_ROBOTS_CACHE``, else ``$XDG_CACHE_HOME/lfd-robots``, else
    ``~/.cache/lfd-robots``."""
    env = os.environ.get("LFD_ROBOTS_CACHE")
    if env:
        return Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base).expanduser() / "lfd-robots"


def _atomic_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file beside it, fsync'ed, then a rename (and
    an fsync of the folder): a crash leaves the old file or the new one, never half of one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    try:
        folder = os.open(path.parent, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(folder)
    except OSError:
        pass
    finally:
        os.close(folder)


def _digest(rgba: np.ndarray, parts: list[bytes]) -> np.ndarray:
    """sha256 of a cache entry's content (its colours and its STL parts), as 32 uint8."""
    h = hashlib.sha256(np.ascontiguousarray(rgba, dtype=np.float64).tobytes())
    for stl in parts:
        h.update(len(stl).to_bytes(8, "little"))
        h.update(stl)
    return np.frombuffer(h.digest(), dtype=np.uint8)


def _read_cache(path: Path) -> list[tuple[bytes, tuple[float, float, float, float]]]:
    """The parts of a cache file (an NPZ: ``rgba`` (n, 4), ``part0..``, ``sha256`` of them,
    ``_digest``); ``ValueError`` with the reason when it is not intact."""
    blob = path.read_bytes()
    if not blob:
        raise ValueError("empty")
    try:
        with np.load(io.BytesIO(blob), allow_pickle=False) as z:
            rgba = np.asarray(z["rgba"], dtype=np.float64)
            parts = [z[f"part{i}"].tobytes() for i in range(len(rgba))]
            digest = np.asarray(z["sha256"])
    except Exception as e:  # noqa: BLE001  a zip or npy reader error of any kind: a damaged file
        raise ValueError(f"truncated or corrupt ({type(e).__name__})") from None
    if rgba.ndim != 2 or rgba.shape[1] != 4 or not np.array_equal(digest, _digest(rgba, parts)):
        raise ValueError("corrupt (checksum mismatch)")
    return [(stl, cast(_RGBA, tuple(float(c) for c in rgba[i]))) for i, stl in enumerate(parts)]


def convert_mesh(path: Path) -> list[tuple[bytes, tuple[float, float, float, float]]]:
    """The mesh file ``path`` (any format trimesh reads; COLLADA needs pycollada) as binary STL
    parts with their colours: [(stl bytes, rgba in [0, 1])], one part per distinct colour, scene
    transforms applied. Raises ``ValueError`` when the file cannot be read.

    Cached in ``cache_dir()`` as ``<stem>-<key>.npz``, ``key`` from the sha256 of the source file
    and ``CONVERTER_VERSION`` (the key of the inputs); the file carries the sha256 of its own
    content (``_digest``). A cache file that is empty, truncated, altered or unreadable is never
    used: the mesh is converted again and the file replaced, after one ``RuntimeWarning``.
    """
    raw = path.read_bytes()
    key = hashlib.sha256(raw + CONVERTER_VERSION.encode()).hexdigest()[:24]
    cached = cache_dir() / f"{path.stem}-{key}.npz"
    if cached.is_file():
        try:
            return _read_cache(cached)
        except (OSError, ValueError) as e:
            reason = f"unreadable ({e.strerror or type(e).__name__})" if isinstance(e, OSError) else str(e)
            warnings.warn(f"robots: mesh cache file {cached} is {reason}; converting {path.name} again",
                          RuntimeWarning, stacklevel=2)
    parts = _convert(raw, path.suffix.lower().lstrip("."))
    rgba = np.array([c for _, c in parts], dtype=np.float64).reshape(-1, 4)
    arrays = {f"part{i}": np.frombuffer(stl, dtype=np.uint8) for i, (stl, _) in enumerate(parts)}
    buf = io.BytesIO()
    # ignore: numpy's stubs let the **arrays match the bool allow_pickle keyword
    np.savez(buf, rgba=rgba, sha256=_digest(rgba, [stl for stl, _ in parts]), **arrays)  # type: ignore[arg-type]
    try:
        _atomic_bytes(cached, buf.getvalue())
    except OSError as e:  # a read-only home: convert again next time
        warnings.warn(f"robots: cannot cache converted meshes in {cache_dir()} ({e.strerror or e})",
                      RuntimeWarning, stacklevel=2)
    return parts


def _convert(raw: bytes, file_type: str) -> list[tuple[bytes, tuple[float, float, float, float]]]:
    try:
        import trimesh
    except ImportError:
        raise ValueError("trimesh is not installed") from None
    try:
        scene = cast(trimesh.Scene, trimesh.load(io.BytesIO(raw), file_type=file_type, force="scene"))
    except Exception as e:  # trimesh and pycollada raise many kinds of errors on bad files
        raise ValueError(f"unreadable mesh ({type(e).__name__}: {str(e)[:80]})") from None
    groups: dict[tuple[int, ...], list] = {}
    for node in scene.graph.nodes_geometry:
        transform, name = scene.graph[node]
        geom = scene.geometry.get(name)
        if geom is None or not hasattr(geom, "faces") or len(geom.faces) == 0:
            continue
        mesh = geom.copy()
        mesh.apply_transform(transform)
        groups.setdefault(_colour(geom), []).append(mesh)
    if not groups:
        raise ValueError("no triangles in the mesh")
    out: list[tuple[bytes, tuple[float, float, float, float]]] = []
    for colour, meshes in sorted(groups.items()):
        merged = cast(trimesh.Trimesh, trimesh.util.concatenate(meshes)) if len(meshes) > 1 else meshes[0]
        vertices, faces = simplify(np.asarray(merged.vertices), np.asarray(merged.faces), CLUSTER_CELL_M)
        if len(faces) < 4 or len(np.unique(faces)) < 4:   # a small part collapsed: keep it whole
            vertices, faces = np.asarray(merged.vertices), np.asarray(merged.faces)
        if len(np.unique(faces)) < 4:                       # MuJoCo needs 4 vertices per mesh
            continue
        out.append((_stl_bytes(vertices, faces), cast(_RGBA, tuple(c / 255.0 for c in colour))))
    if not out:
        raise ValueError("no part of the mesh has 4 vertices")
    return out


def simplify(vertices: np.ndarray, faces: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertex clustering: vertices (V, 3) in one cube of side ``cell`` merge into their mean; faces
    (F, 3) that collapse, and repeated faces, go. Returns (vertices (V', 3), faces (F', 3)).

    CAD meshes carry far more triangles than a frame has pixels for them; a software renderer pays
    per vertex and per light. A grid of a few millimetres keeps the silhouette to a pixel at the
    usual framing and removes most of the Panda's triangles.
    """
    if cell <= 0 or len(faces) == 0:
        return vertices, faces
    keys = np.floor(vertices / cell).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    merged = np.zeros((len(counts), 3))
    np.add.at(merged, inverse, vertices)
    merged /= counts[:, None]
    f = inverse[faces]
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    f = f[keep]
    _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    return merged, f[np.sort(first)]


def _colour(geom: object) -> tuple[int, ...]:
    """The main colour of a trimesh geometry as RGBA uint8 (its material's base colour)."""
    visual = getattr(geom, "visual", None)
    colour = None
    material = getattr(visual, "material", None)
    if material is not None:
        colour = getattr(material, "baseColorFactor", None)
        if colour is None:
            colour = getattr(material, "main_color", None)
    elif visual is not None and getattr(visual, "kind", None) in ("face", "vertex"):
        colour = visual.main_color
    if colour is None:
        return (200, 200, 200, 255)
    c = np.asarray(colour, dtype=np.float64).ravel()
    if c.max() <= 1.0 and c.dtype.kind == "f" and not np.issubdtype(np.asarray(colour).dtype, np.integer):
        c = c * 255.0
    c = np.concatenate([c, [255.0] * (4 - len(c))])[:4]
    return tuple(int(round(v)) for v in np.clip(c, 0, 255))


def _stl_bytes(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    """Binary STL of a triangle mesh: vertices (V, 3), faces (F, 3) int."""
    tri = vertices[faces].astype(np.float32)                        # (F, 3, 3)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.where(norm > 0, normal / np.where(norm > 0, norm, 1.0), 0.0).astype(np.float32)
    rec = np.zeros(len(faces), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    rec["n"], rec["v"] = normal, tri
    return b"lfd-robots visual mesh".ljust(80, b" ") + np.uint32(len(faces)).tobytes() + rec.tobytes()


def _rpy_quat(origin: ET.Element | None) -> tuple[np.ndarray, np.ndarray]:
    """(pos (3,), quat (4,) wxyz) of a URDF <origin xyz rpy> (R = Rz(yaw) Ry(pitch) Rx(roll))."""
    if origin is None:
        return np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0])
    pos = np.array([float(v) for v in origin.get("xyz", "0 0 0").split()])
    r, p, y = (float(v) for v in origin.get("rpy", "0 0 0").split())
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    rot = np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                    [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                    [-sp, cp * sr, cp * cr]])
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, rot.ravel())
    return pos, quat


def _urdf_colours(root: ET.Element) -> dict[str, tuple[float, ...]]:
    """Top-level URDF <material name><color rgba/></material> colours by name."""
    out: dict[str, tuple[float, ...]] = {}
    for m in root.findall("material"):
        c = m.find("color")
        name = m.get("name")
        rgba = c.get("rgba") if c is not None else None
        if name and rgba:
            out[name] = tuple(float(v) for v in rgba.split())
    return out


def add_visuals(spec: mujoco.MjSpec, urdf: Path, assets: dict[str, bytes],
                resolve: Callable[[str, Path], Path], enabled: bool = True) -> VisualReport:
    """Add the URDF's visuals to ``spec`` (bodies named like the links) and their meshes to
    ``assets``; recolour or hide the collision geoms (module docstring).

    resolve : maps a URDF mesh filename (package://, file://, relative) and the URDF's folder to a
        Path; raises ValueError when it cannot.
    enabled : False adds no visuals: every link is drawn with its collision geoms in its colour.
    """
    root = ET.parse(urdf).getroot()
    colours = _urdf_colours(root)
    report = VisualReport()
    materials: dict[tuple[float, ...], str] = {}

    def material(rgba: tuple[float, ...]) -> str:
        key = tuple(round(c, 4) for c in rgba)
        if key not in materials:
            name = f"vis_mat{len(materials)}"
            spec.add_material(name=name, rgba=list(key), specular=0.35, shininess=0.6)
            materials[key] = name
        return materials[key]

    for index, link in enumerate(root.iter("link")):
        name = link.get("name", "")
        body = spec.body(name)
        if body is None:
            continue
        colour = LINK_PALETTE[index % len(LINK_PALETTE)]
        visuals = link.findall("visual") if enabled else []
        added, reason = 0, "no <visual>"
        for vis in visuals:
            try:
                added += _add_visual(spec, body, vis, urdf, assets, resolve, colours, colour, material)
            except (ValueError, OSError) as e:
                reason = str(e)
                added = 0
                break
        if added:
            report.visual_links.append(name)
            report.parts += added
            for g in body.geoms:
                if g.group != VISUAL_GROUP:
                    g.group = COLLISION_GROUP
        else:
            for g in list(body.geoms):
                if g.group == VISUAL_GROUP:  # a half-added link: drop its visuals
                    spec.delete(g)
                else:
                    g.rgba = list(colour)
            if visuals:
                report.fallback[name] = reason
    spec.assets = dict(assets)   # the compiler reads the new mesh files from here
    return report


def _add_visual(spec: mujoco.MjSpec, body: mujoco.MjsBody, vis: ET.Element, urdf: Path,
                assets: dict[str, bytes], resolve: Callable[[str, Path], Path],
                colours: dict[str, tuple[float, ...]], link_colour: tuple[float, ...],
                material: Callable[[tuple[float, ...]], str]) -> int:
    """Geoms of one URDF <visual> added to ``body``; returns how many (0: nothing drawable).
    ``material`` maps an rgba to the name of a shared material; a mesh part without its own
    colour takes the <visual>'s material colour, else ``link_colour``. Raises ValueError or
    OSError when the visual cannot be read."""
    pos, quat = _rpy_quat(vis.find("origin"))
    mat = vis.find("material")
    rgba: tuple[float, ...] | None = None
    if mat is not None:
        color_el = mat.find("color")
        rgba = (tuple(float(v) for v in cast(str, color_el.get("rgba")).split()) if color_el is not None
                else colours.get(mat.get("name", "")))
    geometry = vis.find("geometry")
    if geometry is None or len(geometry) == 0:
        return 0
    shape = geometry[0]
    common = dict(pos=pos, quat=quat, group=VISUAL_GROUP, contype=0, conaffinity=0, mass=0.0)
    if shape.tag == "mesh":
        file = resolve(shape.get("filename", ""), urdf.parent)
        if not file.is_file():
            raise ValueError(f"visual mesh not found: {file}")
        scale = [float(v) for v in shape.get("scale", "1 1 1").split()]
        if file.suffix.lower() in DIRECT_FORMATS:
            parts = [(file.read_bytes(), rgba or link_colour)]
            ext = file.suffix.lower()
        else:
            parts = [(stl, rgba or c) for stl, c in convert_mesh(file)]
            ext = ".stl"
        for i, (data, c) in enumerate(parts):
            asset = f"vis_{body.name}_{file.stem}_{i}{ext}"
            k = 1
            while asset in assets:
                asset, k = f"vis_{body.name}_{file.stem}_{i}_{k}{ext}", k + 1
            assets[asset] = data
            mesh_name = asset.rsplit(".", 1)[0]
            spec.add_mesh(name=mesh_name, file=asset, scale=scale)
            body.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mesh_name, material=material(c), **common)
        return len(parts)
    size = {"box": lambda e: [float(v) / 2 for v in e.get("size").split()],
            "cylinder": lambda e: [float(e.get("radius")), float(e.get("length")) / 2, 0.0],
            "sphere": lambda e: [float(e.get("radius")), 0.0, 0.0]}
    kind = {"box": mujoco.mjtGeom.mjGEOM_BOX, "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
            "sphere": mujoco.mjtGeom.mjGEOM_SPHERE}
    if shape.tag not in kind:
        raise ValueError(f"unsupported visual geometry <{shape.tag}>")
    try:
        s = size[shape.tag](shape)
    except (TypeError, ValueError, AttributeError):
        raise ValueError(f"bad <{shape.tag}> in a <visual>") from None
    body.add_geom(type=kind[shape.tag], size=s, material=material(rgba or link_colour), **common)
    return 1
