"""Robot drawings embedded in the run log, so Foxglove shows the arm without the meshes on disk.

Foxglove draws the URDF on /robot_description only when it can fetch its `package://` meshes
(a ROS package path on the reviewer's machine); Rerun's importer resolves them locally
(`mission.review`). For Foxglove the log also carries /robot/meshes, a `foxglove.SceneUpdate`
with one frame-locked entity per URDF link: a convex hull of the link's mesh (its vertices
snapped to a `HULL_GRID` grid first: ~1 600 triangles, ~35 kB for the Z1 instead of ~33 MB of
meshes) as an embedded glTF binary, plus a box for the Spot body. Hulls are a drawing aid, not
the collision model.
"""

from __future__ import annotations

import functools
import logging
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import unquote, urlparse

import numpy as np

log = logging.getLogger(__name__)

HULL_GRID = 0.003  # m: vertices snapped to this grid before the hull (shape error ≤ 2.6 mm)
GLB_MEDIA_TYPE = "model/gltf-binary"
# glTF is Y-up; Foxglove (like ROS, REP-103) is Z-up and rotates a glTF scene +90° about x on
# load, so link coordinates (x, y, z) are written as (x, z, −y).
Z_UP_TO_GLTF = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])
_LOADABLE = (".stl", ".obj", ".ply", ".off", ".glb")  # formats trimesh reads without extra packages
SPOT_BODY_SIZE = (1.1, 0.5, 0.19)  # m: Spot's body, drawn below the body frame (the arm base's height)


@dataclass(frozen=True)
class LinkMesh:
    link: str  # URDF link name (= the /tf frame it follows)
    origin: np.ndarray  # (4, 4) mesh origin in the link frame (the URDF <origin> of the geometry)
    glb: bytes  # glTF binary of the simplified mesh, in glTF axes
    n_triangles: int


def resolve_mesh(filename: str, urdf_path: Path) -> Path | None:
    """A URDF mesh filename as a local file: `package://NAME/rest` is looked up in the folders
    above the URDF (a folder NAME, or one holding NAME's content as with example-robot-data's
    `share/`), `file://` and relative paths as usual. None when not found."""
    url = urlparse(filename)
    if url.scheme == "package":
        rest = Path(url.netloc) / unquote(url.path).lstrip("/")
        for base in urdf_path.resolve().parents:
            for cand in (base / rest, base.parent / rest):
                if cand.is_file():
                    return cand.resolve()
        return None
    p = Path(unquote(url.path)) if url.scheme == "file" else Path(filename)
    p = p if p.is_absolute() else urdf_path.parent / p
    return p.resolve() if p.is_file() else None


def _origin(el: ET.Element | None) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    if el is not None:
        T[:3, 3] = [float(v) for v in el.get("xyz", "0 0 0").split()]
        T[:3, :3] = Rotation.from_euler("xyz", [float(v) for v in el.get("rpy", "0 0 0").split()]).as_matrix()
    return T


def _loadable(path: Path) -> Path | None:
    """`path` if trimesh reads its format, else a file of the same name in a readable format
    next to it or in a sibling folder (ROS packages keep meshes/visual/X.dae beside
    meshes/collision/X.stl: the Z1's visuals are COLLADA, which needs another package)."""
    if path.suffix.lower() in _LOADABLE:
        return path
    for folder in [path.parent] + sorted(d for d in path.parent.parent.iterdir() if d.is_dir() and d != path.parent):
        for f in sorted(folder.iterdir()):
            if f.stem == path.stem and f.suffix.lower() in _LOADABLE and f.is_file():
                return f
    return None


def _link_geometry(link: ET.Element, urdf_path: Path) -> tuple[Path, np.ndarray, np.ndarray] | None:
    """(mesh file, origin, scale) of a link's first visual mesh (else collision mesh) that can be read."""
    for tag in ("visual", "collision"):
        for geo_el in link.findall(tag):
            mesh = geo_el.find("geometry/mesh")
            path = None if mesh is None else resolve_mesh(mesh.get("filename", ""), urdf_path)
            path = None if path is None else _loadable(path)
            if path is None:
                continue
            scale = np.array([float(v) for v in mesh.get("scale", "1 1 1").split()])
            return path, _origin(geo_el.find("origin")), scale
    return None


def _hull_glb(path: Path, scale: np.ndarray) -> tuple[bytes, int]:
    import trimesh

    m = trimesh.load(path, force="mesh")
    v = np.unique(np.round(np.asarray(m.vertices) * scale / HULL_GRID), axis=0) * HULL_GRID
    hull = trimesh.PointCloud(v).convex_hull
    hull.apply_transform(Z_UP_TO_GLTF)
    return trimesh.exchange.gltf.export_glb(trimesh.Scene(hull)), len(hull.faces)


@functools.lru_cache(maxsize=4)
def _link_meshes_cached(urdf_path: Path, mtime_ns: int) -> tuple[LinkMesh, ...]:
    root = ET.parse(urdf_path).getroot()
    out, missing = [], []
    for link in root.findall("link"):
        geo = _link_geometry(link, urdf_path)
        if geo is None:
            if link.find("visual") is not None:
                missing.append(link.get("name", "?"))
            continue
        path, origin, scale = geo
        try:
            glb, n = _hull_glb(path, scale)
        except Exception as e:  # noqa: BLE001 - a drawing aid must not stop a run
            log.warning("robot meshes: %s (%s) not drawn: %s", link.get("name"), path.name, e)
            continue
        out.append(LinkMesh(link.get("name", "?"), origin, glb, n))
    if missing:
        log.warning("robot meshes: no readable mesh for link(s) %s; Foxglove shows them as frames only", ", ".join(missing))
    return tuple(out)


def link_meshes(urdf_path: Path) -> tuple[LinkMesh, ...]:
    """The simplified link meshes of a URDF (cached per file version); empty if it has none."""
    try:
        p = Path(urdf_path).resolve()
        return _link_meshes_cached(p, p.stat().st_mtime_ns)
    except Exception as e:  # noqa: BLE001 - unreadable URDF: the run log says so, the run goes on
        log.warning("robot meshes: cannot read %s: %s", urdf_path, e)
        return ()
