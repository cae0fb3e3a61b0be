"""A run log read by a foreign client: the JavaScript stack Foxglove uses (@mcap/core, protobufjs),
bench/foreign_reader/read.mjs, which shares no code with our writer or reader. Slow (npm install
from the registry, ~10 s); skipped where node/npm are missing. `make test PYTEST_ARGS='-m slow'`."""

from __future__ import annotations

import json
import shutil
import subprocess
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from capm_field.camera import PinholeCamera
from capm_field.config import CameraConfig
from mission.runlog import RunLog
from mission.runlog_read import iter_run
from mission.runlog_synth import synthetic_mission

pytestmark = [pytest.mark.slow, pytest.mark.skipif(not (shutil.which("node") and shutil.which("npm")), reason="needs node and npm")]
READER = Path(__file__).resolve().parents[1] / "bench" / "foreign_reader"


def test_every_message_decodes_in_foxglove_s_javascript_stack(tmp_path, robot):
    run = tmp_path / "run.mcap"
    with RunLog(run, robot, PinholeCamera.from_config(CameraConfig()), bench=True) as log:
        synthetic_mission(log, n_targets=2, seconds_per_target=1.0, images_per_target=1, width=640, height=360)
    js = tmp_path / "reader"
    js.mkdir()
    for f in ("package.json", "read.mjs"):
        shutil.copy(READER / f, js / f)
    subprocess.run(["npm", "install", "--no-audit", "--no-fund", "--loglevel=error"], cwd=js, check=True, timeout=300)
    out = subprocess.run(["node", "read.mjs", str(run)], cwd=js, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    topics = got["topics"]

    assert {t: v["count"] for t, v in topics.items()} == dict(Counter(m.topic for m in iter_run(run)))
    assert got["metadata"]["capm_run"]["bench"] == "true"
    ign = topics["/igniter/state"]["first"]
    assert ign["flameOn"] in (True, False) and 0.0 <= ign["fuel"] <= 1.0
    assert topics["/robot_description"]["first"]["data"] == robot.urdf_path.read_text()
    meshes = topics["/robot/meshes"]["first"]["entities"]
    glb = [e["models"][0]["data"] for e in meshes if e["models"]]
    assert len(glb) == 9 and all(d["head"] == list(b"glTF") for d in glb)
    tf = topics["/tf"]["first"]["transforms"]
    q = np.array([[x["rotation"][k] for k in "xyzw"] for x in tf])
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0)
    assert topics["/plan"]["schema"] == "capm.log.Plan" and topics["/plan"]["first"]["targetId"]
