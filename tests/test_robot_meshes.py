"""/robot/meshes (mission/robot_meshes.py): the arm drawn from the run log alone, for Foxglove.

Read back from a real MCAP file: one frame-locked glTF entity per Z1 link, in glTF's Y-up axes
(Foxglove turns them Z-up), each the hull of that link's mesh; a URDF whose meshes are missing
gives a log without them, not a failed run."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
import trimesh
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from scipy.spatial import Delaunay

from capm_field.camera import PinholeCamera
from capm_field.config import CameraConfig
from capm_field.geometry import SE2
from capm_field.robot_model import default_urdf_path
from mission.robot_meshes import GLB_MEDIA_TYPE, HULL_GRID, Z_UP_TO_GLTF, link_meshes, resolve_mesh
from mission.runlog import RunLog

T0 = 5_000_000_000


def _scene(path: Path):
    with path.open("rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        msgs = [(schema, m) for schema, _, m in reader.iter_messages(topics=["/robot/meshes"])]
    assert len(msgs) == 1
    schema, msg = msgs[0]
    assert schema.name == "foxglove.SceneUpdate"
    return msg.log_time, DecoderFactory().decoder_for("protobuf", schema)(msg.data)


def glb_vertices(glb: bytes) -> np.ndarray:
    """Vertices of a glTF binary back in Z-up link coordinates."""
    v = trimesh.load(trimesh.util.wrap_as_stream(glb), file_type="glb").to_geometry().vertices
    return (np.c_[v, np.ones(len(v))] @ np.linalg.inv(Z_UP_TO_GLTF).T)[:, :3]


@pytest.fixture(scope="module")
def logged_scene(tmp_path_factory, robot):
    path = tmp_path_factory.mktemp("meshes") / "run.mcap"
    with RunLog(path, robot, PinholeCamera.from_config(CameraConfig()), bench=True) as log:
        log.transforms(T0, SE2(0.0, 0.0, 0.0), np.zeros(6))
    return _scene(path)


def test_every_z1_link_is_drawn_in_its_own_frame(logged_scene, robot):
    t, scene = logged_scene
    assert t == T0
    by_id = {e.id: e for e in scene.entities}
    links = [f"link0{k}" for k in range(7)] + ["gripperStator", "gripperMover"]
    assert {f"link:{n}" for n in links} | {"spot_body"} == set(by_id)
    for n in links:
        e = by_id[f"link:{n}"]
        assert e.frame_id == n and e.frame_locked and len(e.models) == 1
        m = e.models[0]
        assert m.media_type == GLB_MEDIA_TYPE and m.data[:4] == b"glTF" and not m.url
    assert by_id["spot_body"].frame_id == "body" and len(by_id["spot_body"].cubes) == 1
    assert sum(len(e.models[0].data) for e in scene.entities if e.models) < 100_000  # a drawing, not the 33 MB of meshes


def test_glb_is_y_up_and_holds_the_link_mesh(logged_scene):
    """link00 (the base, z from 0 to 5.8 cm in the URDF) stands along glTF's +y; every vertex of
    the original STL of each link lies inside its hull (grown by the grid's snapping error)."""
    _, scene = logged_scene
    by_link = {e.frame_id: e.models[0].data for e in scene.entities if e.models}
    raw = trimesh.load(trimesh.util.wrap_as_stream(by_link["link00"]), file_type="glb").to_geometry().vertices
    assert raw[:, 1].min() > -0.002 and 0.05 < raw[:, 1].max() < 0.062  # glTF y = URDF z
    assert abs(raw[:, 2]).max() < 0.06
    stl_dir = default_urdf_path().parents[1] / "meshes" / "collision"
    for link, stl in (("link02", "z1_Link02.STL"), ("link03", "z1_Link03.STL"), ("gripperMover", "z1_GripperMover.STL")):
        v = glb_vertices(by_link[link])
        orig = trimesh.load(stl_dir / stl, force="mesh").vertices
        hull = Delaunay(v)
        centre = v.mean(0)
        shrunk = centre + (orig - centre) * 0.97  # inside up to the snapping error on a few-cm link
        inside = hull.find_simplex(shrunk) >= 0
        assert inside.mean() > 0.99, (link, inside.mean())
        assert np.all(v.min(0) > orig.min(0) - HULL_GRID) and np.all(v.max(0) < orig.max(0) + HULL_GRID)


def test_resolve_mesh_forms(tmp_path):
    pkg = tmp_path / "share" / "my_robot"
    (pkg / "meshes").mkdir(parents=True)
    (pkg / "urdf").mkdir()
    mesh = pkg / "meshes" / "a.stl"
    mesh.write_bytes(b"solid a\nendsolid a\n")
    urdf = pkg / "urdf" / "r.urdf"
    assert resolve_mesh("package://my_robot/meshes/a.stl", urdf) == mesh
    assert resolve_mesh("../meshes/a.stl", urdf) == mesh
    assert resolve_mesh(f"file://{mesh}", urdf) == mesh
    assert resolve_mesh("package://other_pkg/meshes/a.stl", urdf) is None
    assert resolve_mesh("package://my_robot/meshes/missing.stl", urdf) is None


def test_missing_or_broken_meshes_leave_the_links_undrawn(tmp_path, caplog):
    bad = tmp_path / "broken.stl"
    bad.write_bytes(b"\x00not a mesh")
    urdf = tmp_path / "r.urdf"
    urdf.write_text(
        '<robot name="r">'
        '<link name="a"><visual><geometry><mesh filename="package://nowhere/a.stl"/></geometry></visual></link>'
        '<link name="b"><visual><geometry><mesh filename="broken.stl"/></geometry></visual></link>'
        '<link name="c"><visual><geometry><box size="1 1 1"/></geometry></visual></link>'
        "</robot>"
    )
    with caplog.at_level(logging.WARNING):
        assert link_meshes(urdf) == ()
    assert "not drawn" in caplog.text and "no readable mesh" in caplog.text
    assert link_meshes(tmp_path / "absent.urdf") == ()
