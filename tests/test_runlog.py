"""Run log (mission/runlog.py): real MCAP files read back with the `mcap` reader.

Every method round-trips with CRC validation and decoding through the embedded schemas; the
frame tree and topics match docs/log.md; an uncaught exception or Ctrl-C still finalises the
file; after SIGKILL the file is readable up to ≤ 1 s before the kill.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Channel, Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap_protobuf.decoder import DecoderFactory
from scipy.spatial.transform import Rotation

from capm_field.camera import PinholeCamera
from capm_field.config import CameraConfig
from capm_field.errors import UserError
from capm_field.geometry import SE2
from capm_field.keystates import TROI, KeyState, Plan
from mission.runlog import TOPICS, RunLog, quaternions
from mission.runlog_read import ReadReport, decode_cdr_string, iter_run, salvage

REPO = Path(__file__).resolve().parents[1]
T0 = 5_000_000_000


@pytest.fixture(scope="module")
def camera() -> PinholeCamera:
    return PinholeCamera.from_config(CameraConfig())


def _plan() -> tuple[TROI, Plan]:
    troi = TROI(2.0, 0.5, 0.05, "w1")
    k1 = SE2(1.4, 0.3, 0.2)
    ks = (
        KeyState("x_k0", SE2(0.0, 0.0, 0.0)),
        KeyState("x_b,k1", k1),
        KeyState("x_e,k2", k1, arm="observe", target=troi.xy, radius=troi.r),
        KeyState("x_e,k3", k1, arm="flame", target=troi.xy),
        KeyState("x_kmax", SE2(2.5, 0.0, 0.0)),
    )
    plan = Plan("capm", troi, SE2(0, 0, 0), SE2(2.5, 0, 0), ks, 0.75, 13.25, SE2(1.6, 0.5, 0.0), {"objective": 13.25, "note": "x"})
    return troi, plan


def write_full_log(path: Path, robot, camera, bench: bool = True) -> dict:
    """One call of every method; returns what was logged, for the checks."""
    troi, plan = _plan()
    q = np.array([0.3, 0.8, -1.2, 0.3, 0.5, -0.4])
    body = SE2(1.4, 0.3, 0.2)
    img = np.zeros((camera.height, camera.width, 3), np.uint8)
    img[100:200, 300:500] = (0, 200, 0)
    with RunLog(path, robot, camera, bench=bench) as log:
        log.transforms(T0, body, q)
        log.image(T0 + 1, img, "w1")
        log.event(T0 + 2, "warning", "interlock open", target="w1", reason="epmc")
        log.plan(T0 + 3, "w1", plan)
        log.key_state(T0 + 4, "w1", "capm", plan.key_states[2], note="observe")
        log.detection(T0 + 5, "w1", (640.5, 360.25), 0.93, None, (2.01, 0.48))
        log.detection(T0 + 6, "w1", None, 0.1, "low_contrast", None)
        log.regions(T0 + 7, "w1", troi, [(0.35, 0.62)], [(0.3, 0.5), (0.6, 0.7)], (2.01, 0.48))
        log.energy(T0 + 8, 42.5, "w1", 12.0, 2)
        log.igniter(T0 + 9, True, True, 0.8, None, True, [], True, True, False)
        log.igniter(T0 + 10, False, True, 0.79, "flame_out", False, ["epmc", "moving"], False, False, True)
        log.truth_mpoi(T0 + 11, "w1", (2.012, 0.478))
    return {"q": q, "body": body, "plan": plan, "img": img}


def read_all(path: Path):
    with path.open("rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        out: dict[str, list] = {}
        for schema, channel, message in reader.iter_messages():
            if channel.message_encoding == "protobuf":
                decoded = DecoderFactory().decoder_for(channel.message_encoding, schema)(message.data)
            else:
                decoded = message.data
            out.setdefault(channel.topic, []).append((message.log_time, schema, channel, decoded))
    return summary, out


@pytest.fixture(scope="module")
def full_log(tmp_path_factory, robot, camera):
    path = tmp_path_factory.mktemp("runlog") / "run.mcap"
    logged = write_full_log(path, robot, camera)
    summary, msgs = read_all(path)
    return path, logged, summary, msgs


def test_file_is_finalised_with_summary_and_crcs(full_log):
    path, _, summary, msgs = full_log
    assert summary is not None and summary.statistics is not None
    assert summary.statistics.message_count == sum(len(v) for v in msgs.values())
    assert len(summary.chunk_indexes) >= 1


def test_igniter_state_decodes_with_boolean_flame_on(full_log):
    msgs = full_log[3]["/igniter/state"]
    (t1, schema, channel, on), (t2, _, _, off) = msgs
    assert schema.name == "capm.log.IgniterStatus" and schema.encoding == "protobuf" and channel.message_encoding == "protobuf"
    assert on.flame_on is True and off.flame_on is False
    assert on.armed and on.interlock_ok and on.epmc_ok and not on.estop
    assert off.fault == "flame_out" and list(off.interlock_reasons) == ["epmc", "moving"] and off.estop
    assert on.fuel == pytest.approx(0.8)
    assert t1 == T0 + 9 and on.timestamp.ToNanoseconds() == T0 + 9


def test_plan_key_state_detection_regions_energy_truth(full_log):
    _, logged, _, msgs = full_log
    plan = msgs["/plan"][0][3]
    assert plan.planner == "capm" and plan.p_upper == pytest.approx(0.75) and plan.expected_cost == pytest.approx(13.25)
    assert [k.label for k in plan.key_states] == [k.label for k in logged["plan"].key_states]
    assert plan.troi.id == "w1" and plan.troi.r == pytest.approx(0.05)
    assert plan.fallback_k3.x == pytest.approx(1.6)
    assert {t.name: t.value for t in plan.terms} == {"objective": 13.25}  # non-numeric terms dropped

    ks = msgs["/key_state"][0][3]
    assert ks.label == "x_e,k2" and ks.arm == "observe" and ks.radius == pytest.approx(0.05) and ks.note == "observe"
    assert ks.body.yaw == pytest.approx(0.2) and ks.HasField("target") and ks.frame_id == "field"

    found, missed = (m[3] for m in msgs["/detection"])
    assert found.found and found.pixel.x == pytest.approx(640.5) and found.mpoi_field.y == pytest.approx(0.48)
    assert not missed.found and not missed.HasField("pixel") and not missed.HasField("mpoi_field")
    assert missed.reason == "low_contrast"

    reg = msgs["/regions"][0][3]
    assert [(a.r_inner, a.r_outer) for a in reg.ro] == [(0.35, 0.62)]
    assert [(a.r_inner, a.r_outer) for a in reg.rm] == [(0.3, 0.5), (0.6, 0.7)]
    assert reg.mpoi.x == pytest.approx(2.01)

    en = msgs["/energy"][0][3]
    assert (en.total, en.target_id, en.target_energy, en.body_moves) == (42.5, "w1", 12.0, 2)

    truth = msgs["/truth/mpoi"][0][3]
    assert truth.mpoi.x == pytest.approx(2.012) and truth.frame_id == "field"


def test_foxglove_topics_image_calibration_log_urdf(full_log, robot, camera):
    _, logged, _, msgs = full_log
    img = msgs["/camera/image"][0][3]
    assert msgs["/camera/image"][0][1].name == "foxglove.CompressedImage"
    assert img.format == "jpeg" and img.frame_id == "camera"
    decoded = cv2.imdecode(np.frombuffer(img.data, np.uint8), cv2.IMREAD_COLOR)
    assert decoded.shape == logged["img"].shape
    assert np.abs(decoded.astype(int) - logged["img"]).mean() < 3.0

    cal = msgs["/camera/calibration"][-1][3]
    assert msgs["/camera/calibration"][-1][1].name == "foxglove.CameraCalibration"
    assert (cal.width, cal.height, cal.frame_id) == (camera.width, camera.height, "camera")
    assert np.allclose(np.reshape(cal.K, (3, 3)), camera.K)

    logs = [m[3] for m in msgs["/log"]]
    warn = next(m for m in logs if m.message.startswith("interlock open"))
    assert "target=w1" in warn.message and "reason=epmc" in warn.message and warn.level == 3  # WARNING

    (t, schema, channel, data) = msgs["/robot_description"][0]
    assert (schema.name, schema.encoding, channel.message_encoding) == ("std_msgs/msg/String", "ros2msg", "cdr")
    assert decode_cdr_string(data) == robot.urdf_path.read_text()


def test_frame_tree(full_log, robot):
    """field → body → arm_base → URDF links (URDF names) → camera / nozzle; composes to the FK."""
    _, logged, _, msgs = full_log
    (t, schema, _, tf) = msgs["/tf"][0]
    assert schema.name == "foxglove.FrameTransforms"
    parent = {x.child_frame_id: x.parent_frame_id for x in tf.transforms}
    assert {"field", "body", "arm_base", "camera", "nozzle"} <= set(parent) | set(parent.values())
    assert parent["body"] == "field" and parent["arm_base"] == "body"
    assert parent["camera"] == parent["nozzle"] == robot.cfg.arm.flange_frame
    urdf_links = set(re.findall(r'<link name="([^"]+)"', robot.urdf_path.read_text()))
    assert urdf_links <= set(parent) | set(parent.values())

    local = {}
    for x in tf.transforms:
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat([x.rotation.x, x.rotation.y, x.rotation.z, x.rotation.w]).as_matrix()
        T[:3, 3] = (x.translation.x, x.translation.y, x.translation.z)
        local[x.child_frame_id] = T

    def in_field(frame: str) -> np.ndarray:
        return np.eye(4) if frame == "field" else in_field(parent[frame]) @ local[frame]

    fk = robot.fk(logged["q"])
    T_fb = robot.T_field_base(logged["body"])
    for frame in ("camera", "nozzle", "link03"):
        assert np.allclose(in_field(frame), T_fb @ fk[frame], atol=1e-9)


def test_every_documented_topic_is_written(full_log):
    doc = (REPO / "docs" / "log.md").read_text()
    documented = set(re.findall(r"^\| `(/[a-z_/]+)`", doc, flags=re.M))
    assert documented == set(TOPICS.values())
    assert documented <= set(full_log[3])


def test_truth_is_not_logged_on_hardware(tmp_path, robot, camera):
    path = tmp_path / "hw.mcap"
    write_full_log(path, robot, camera, bench=False)
    _, msgs = read_all(path)
    assert "/truth/mpoi" not in msgs and "/igniter/state" in msgs


def test_refuses_to_overwrite_and_bad_level(tmp_path, robot, camera):
    path = tmp_path / "run.mcap"
    path.write_bytes(b"x")
    with pytest.raises(UserError, match="already exists"):
        RunLog(path, robot, camera, bench=True)
    with RunLog(tmp_path / "b.mcap", robot, camera, bench=True) as log:
        with pytest.raises(ValueError, match="level"):
            log.event(T0, "loud", "x")
    log.close()  # idempotent
    log.event(T0, "info", "after close is ignored")


@pytest.mark.parametrize(
    "dist, model, D",
    [
        ((), "plumb_bob", [0.0] * 5),
        ((-0.3, 0.1, 0.0005, -0.0008), "plumb_bob", [-0.3, 0.1, 0.0005, -0.0008, 0.0]),
        ((-0.3, 0.1, 0.0, 0.0, 0.0, 0.01, 0.02, 0.0), "rational_polynomial", [-0.3, 0.1, 0.0, 0.0, 0.0, 0.01, 0.02, 0.0]),
    ],
)
def test_calibration_carries_the_lens_distortion(tmp_path, robot, dist, model, D):
    """Foxglove and Rerun read the lens from /camera/calibration: ROS's names and coefficient counts."""
    cam = PinholeCamera.from_config(CameraConfig(distortion=dist))
    with RunLog(tmp_path / "run.mcap", robot, cam, bench=True) as log:
        log.image(T0, np.zeros((cam.height, cam.width, 3), np.uint8), "w1")
    _, msgs = read_all(tmp_path / "run.mcap")
    cal = msgs["/camera/calibration"][-1][3]
    assert cal.distortion_model == model and list(cal.D) == pytest.approx(D)


def test_quaternions_match_scipy():
    R = Rotation.random(500, random_state=3).as_matrix()
    R = np.concatenate([R, np.diag([1.0, -1, -1])[None], np.diag([-1.0, 1, -1])[None], np.diag([-1.0, -1, 1])[None]])
    q = quaternions(R)
    ref = Rotation.from_matrix(R).as_quat()
    assert np.allclose(np.abs(np.sum(q * ref, axis=1)), 1.0, atol=1e-12)


# ---- process-level behaviour -------------------------------------------------------------------
_CHILD_PRELUDE = """
import sys, time
import numpy as np
from capm_field.camera import PinholeCamera
from capm_field.config import CameraConfig, RobotConfig
from capm_field.geometry import SE2
from capm_field.robot_model import RobotModel
from mission.runlog import RunLog
from mission.runlog_synth import synthetic_image
robot = RobotModel(RobotConfig())
cam = PinholeCamera.from_config(CameraConfig())
log = RunLog(sys.argv[1], robot, cam, bench=True, flush_period_s=float(sys.argv[2]))
"""


def _child(tmp_path: Path, body: str) -> Path:
    script = tmp_path / "child.py"
    script.write_text(_CHILD_PRELUDE + textwrap.dedent(body))
    return script


@pytest.mark.parametrize("ending", ["raise RuntimeError('boom')", "raise KeyboardInterrupt"])
def test_uncaught_exception_still_finalises(tmp_path, ending):
    script = _child(tmp_path, f"""
        for i in range(20):
            log.transforms(i * 50_000_000, SE2(0.1 * i, 0, 0), np.zeros(6))
        log.event(10**9, "error", "about to fail")
        {ending}
    """)
    path = tmp_path / "run.mcap"
    proc = subprocess.run([sys.executable, str(script), str(path), "10"], cwd=REPO, capture_output=True, timeout=60)
    assert proc.returncode != 0
    summary, msgs = read_all(path)  # a footer and summary: close() ran at exit
    assert summary is not None and summary.statistics.message_count == len(msgs["/tf"]) + 4  # + log, urdf, calibration, meshes
    assert len(msgs["/tf"]) == 20


def test_sigkill_loses_at_most_one_second(tmp_path):
    """A writer logging in real time (wall-clock stamps) is SIGKILLed; the streaming reader
    still returns every message older than ≤ 1 s before the kill, with no holes."""
    script = _child(tmp_path, """
        img = synthetic_image(cam.width, cam.height, 0)
        print("ready", flush=True)
        i = 0
        while True:
            t = time.time_ns()
            log.transforms(t, SE2(0.01 * i, 0, 0), np.full(6, 0.001 * i))
            if i % 5 == 0:
                log.igniter(t, i % 10 == 0, True, 1.0, None, True, [], True, True, False)
            if i == 0:  # one image only: later chunks close by the flusher alone (the worst case)
                log.image(t, img, "t")
            i += 1
            time.sleep(0.02)
    """)
    path = tmp_path / "run.mcap"
    flush_period = 0.5
    proc = subprocess.Popen([sys.executable, str(script), str(path), str(flush_period)], cwd=REPO, stdout=subprocess.PIPE)
    try:
        assert proc.stdout.readline().strip() == b"ready"
        time.sleep(float(os.environ.get("CAPM_KILL_AFTER_S", "2.3")))  # phase vs the flusher varies with start-up
        t_kill = time.time_ns()
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    report = ReadReport()
    stamps = [m.log_time for m in iter_run(path, topics={"/tf"}, report=report)]
    assert not report.complete  # no footer: this really is a crash file
    assert stamps, "nothing readable after the kill"
    gap_s = (t_kill - max(stamps)) / 1e9
    holes_s = float(np.max(np.diff(stamps))) / 1e9 if len(stamps) > 1 else 0.0
    print(f"\nSIGKILL: {len(stamps)} transforms readable over {(stamps[-1] - stamps[0]) / 1e9:.2f} s, "
          f"last one {gap_s * 1e3:.0f} ms before the kill (flush period {flush_period} s), largest hole {holes_s * 1e3:.0f} ms, "
          f"tail: {report.error}")
    assert gap_s <= 1.0
    assert holes_s < 0.3  # messages are lost only at the tail, never in between

    # The stock `mcap` streaming reader (no summary needed) gets the same messages.
    stock = []
    with path.open("rb") as f:
        try:
            for _, channel, message in NonSeekingReader(f, validate_crcs=True).iter_messages(log_time_order=False):
                if channel.topic == "/tf":
                    stock.append(message.log_time)
        except Exception:  # noqa: BLE001 - the torn tail ends the read
            pass
    assert stock == stamps

    # salvage() makes a finalised copy that the summary-based reader opens.
    fixed = tmp_path / "salvaged.mcap"
    assert salvage(path, fixed).messages == sum(1 for _ in iter_run(path))
    summary, msgs = read_all(fixed)
    assert summary is not None and [m[0] for m in msgs["/tf"]] == stamps


def test_python_warnings_and_tracebacks_go_to_the_log_topic(tmp_path, robot, camera):
    """`RunLogHandler`: a WARNING record and an ERROR with its traceback become /log lines named
    after their logger, at the matching level; INFO stays out (handler level WARNING)."""
    import logging

    from mission.runlog import RunLogHandler

    path = tmp_path / "run.mcap"
    lg = logging.getLogger("capm_field.test_runlog_handler")
    lg.propagate = False  # this test's records go to the handler only
    with RunLog(path, robot, camera, bench=True) as log:
        h = RunLogHandler(log, lambda: T0)
        lg.addHandler(h)
        try:
            lg.info("not kept")
            lg.warning("zenoh session %s lost", "body")
            try:
                raise RuntimeError("bug in stage 2")
            except RuntimeError:
                lg.exception("detector failed")
        finally:
            lg.removeHandler(h)
            lg.propagate = True
    _, msgs = read_all(path)
    lines = [(m[3].name, m[3].level, m[3].message) for m in msgs["/log"] if m[3].name == lg.name]
    assert [(lv, t.splitlines()[0]) for _, lv, t in lines] == [(3, "zenoh session body lost"), (4, "detector failed")]
    assert "RuntimeError: bug in stage 2" in lines[1][2] and "Traceback" in lines[1][2]


def test_a_damaged_chunk_is_skipped_and_the_rest_is_read(tmp_path, robot, camera):
    """One flipped byte (a bad sector) in the chunk that holds the /tf Channel record: that chunk's
    messages are lost (it may hold no /tf message: the record goes where the chunk before the first
    /tf message ends), every other chunk's are read (the channel from the summary), the damage is
    reported, and salvage() copies the rest into a clean file."""
    path = tmp_path / "run.mcap"
    with RunLog(path, robot, camera, bench=True, chunk_size=4096) as log:
        for i in range(300):
            log.transforms(T0 + i * 1_000_000, SE2(0.01 * i, 0, 0), np.full(6, 0.001 * i))
    clean = [m.log_time for m in iter_run(path, topics={"/tf"})]
    with path.open("rb") as f:
        chunks = sorted(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    with path.open("rb") as f:  # what each chunk holds, from the clean file (same order)
        inner = [breakup_chunk(r) for r in StreamReader(f, emit_chunks=True).records if isinstance(r, Chunk)]
    assert len(chunks) == len(inner) >= 4
    k = next(i for i, recs in enumerate(inner) if any(isinstance(r, Channel) and r.topic == "/tf" for r in recs))
    tf_id = next(r.id for r in inner[k] if isinstance(r, Channel) and r.topic == "/tf")
    lost = {r.log_time for r in inner[k] if isinstance(r, Message) and r.channel_id == tf_id}
    data = bytearray(path.read_bytes())
    data[chunks[k].chunk_start_offset + chunks[k].chunk_length - 20] ^= 0xFF  # inside its compressed records
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))

    report = ReadReport()
    got = [m.log_time for m in iter_run(bad, topics={"/tf"}, report=report)]
    assert report.bad_chunks == 1 and report.complete and report.error is None
    assert "1 damaged chunk" in report.damage_note()
    assert got == [t for t in clean if t not in lost] and len(got) > len(clean) / 2
    fixed = tmp_path / "fixed.mcap"
    assert salvage(bad, fixed).messages == sum(1 for _ in iter_run(bad))
    summary, msgs = read_all(fixed)
    assert [m[0] for m in msgs["/tf"]] == got
