"""The run log: one MCAP file per run, written with foxglove-sdk, readable after a crash.

Foxglove schemas where one fits (FrameTransforms, CompressedImage, CameraCalibration, Log,
SceneUpdate: the arm's simplified meshes, `mission.robot_meshes`), the Z1 URDF as a ROS 2
`std_msgs/String` (cdr) on /robot_description so Rerun and Foxglove draw the arm, and protobuf messages with their FileDescriptorSet embedded for the rest
(`mission.runlog_schema`). Topics, schemas, frames and rates: docs/log.md.

Crash safety (SIGKILL, power cut of the process): foxglove-sdk's MCAP writer buffers messages
in an open chunk; `MCAPWriter.flush()` closes that chunk and writes it to the OS. A background
thread calls it every `flush_period_s` when something was logged, so after a kill everything
older than ~flush_period_s (+ the time one flush takes) is in complete, CRC-checked chunks that
a streaming MCAP reader (no footer/summary needed) returns; see `mission.runlog_read`.
No fsync: a kernel crash or power loss of the computer can still lose the page cache.
"""

from __future__ import annotations

import atexit
import logging
import struct
import threading
import time
import traceback
import xml.etree.ElementTree as ET
from pathlib import Path

import cv2
import foxglove
import numpy as np
from foxglove import Channel, Context, Schema
from foxglove.channels import (
    CameraCalibrationChannel,
    CompressedImageChannel,
    FrameTransformsChannel,
    LogChannel,
    SceneUpdateChannel,
)
from foxglove.mcap import MCAPCompression, MCAPWriteOptions
from foxglove.messages import (
    CameraCalibration,
    Color,
    CompressedImage,
    CubePrimitive,
    FrameTransform,
    FrameTransforms,
    Log,
    LogLevel,
    ModelPrimitive,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    Timestamp,
    Vector3,
)

from capm_field.camera import PinholeCamera
from capm_field.errors import UserError
from capm_field.geometry import SE2
from capm_field.keystates import TROI, KeyState, Plan
from capm_field.robot_model import RobotModel

from . import runlog_schema as S
from .robot_meshes import GLB_MEDIA_TYPE, SPOT_BODY_SIZE, link_meshes

# Topic names (docs/log.md lists them all; tests check the two agree).
TOPICS = {
    "tf": "/tf",
    "image": "/camera/image",
    "calibration": "/camera/calibration",
    "log": "/log",
    "robot_description": "/robot_description",
    "plan": "/plan",
    "key_state": "/key_state",
    "detection": "/detection",
    "regions": "/regions",
    "energy": "/energy",
    "igniter": "/igniter/state",
    "truth_mpoi": "/truth/mpoi",
    "robot_meshes": "/robot/meshes",
}
PROTO_TOPICS = {
    "plan": "Plan",
    "key_state": "KeyState",
    "detection": "Detection",
    "regions": "Regions",
    "energy": "Energy",
    "igniter": "IgniterStatus",
    "truth_mpoi": "TruthMpoi",
}
# the schema each topic that readers decode carries (a message of another one, from a foreign or
# hand-made file, is skipped: `runlog_schema.foreign_problem`)
SCHEMAS = {TOPICS[k]: S.full_name(v) for k, v in PROTO_TOPICS.items()} | {
    TOPICS["tf"]: "foxglove.FrameTransforms", TOPICS["image"]: "foxglove.CompressedImage",
    TOPICS["calibration"]: "foxglove.CameraCalibration"}
FIELD, BODY, ARM_BASE, CAMERA, NOZZLE = "field", "body", "arm_base", "camera", "nozzle"

_LEVELS = {
    "debug": LogLevel.Debug,
    "info": LogLevel.Info,
    "warning": LogLevel.Warning,
    "error": LogLevel.Error,
    "fatal": LogLevel.Fatal,
}
_ROS2_STRING = Schema(name="std_msgs/msg/String", encoding="ros2msg", data=b"string data")

# The RunLog whose write is running on this thread (set in RunLog._emit with its lock held).
# foxglove-sdk reports a failed sink write (a full disk, a file size limit) as a Python log
# warning from inside that write: a handler that logs into the run log must not re-enter it
# (RunLog's lock is not re-entrant: the run hung for good on it).
_WRITING = threading.local()
SINK_LOGGER = "foxglove.log_sink_set"  # the logger foxglove-sdk reports sink write failures on


class _SinkErrors(logging.Filter):
    """On foxglove's sink logger: the first write failure of a RunLog is kept as its
    `write_error` and shown once; the same RunLog's later ones (every message after a failure
    fails: "attempted another write after a write method failed") are dropped."""

    def filter(self, record: logging.LogRecord) -> bool:
        log = getattr(_WRITING, "log", None)
        if log is None:
            return True
        if log.write_error is not None:
            return False
        log.write_error = record.getMessage()
        return True


_sink_filter = _SinkErrors()


def urdf_tree(urdf_text: str) -> dict[str, str]:
    """child link -> parent link, from the URDF's joints."""
    root = ET.fromstring(urdf_text)
    return {j.find("child").get("link"): j.find("parent").get("link") for j in root.iter("joint") if j.find("child") is not None}


def cdr_string(text: str) -> bytes:
    """A ROS 2 std_msgs/String in CDR (little-endian encapsulation, NUL-terminated string)."""
    b = text.encode("utf-8") + b"\x00"
    return b"\x00\x01\x00\x00" + struct.pack("<I", len(b)) + b


def quaternions(R: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions (x, y, z, w) of rotation matrices (N, 3, 3), w ≥ 0.

    Per matrix, the largest of 4w², 4x², 4y², 4z² picks the numerically safe formula.
    """
    R = np.asarray(R, dtype=float).reshape(-1, 3, 3)
    m00, m11, m22 = R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]
    d = np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], axis=1)
    k = np.argmax(d, axis=1)
    s = 2.0 * np.sqrt(np.maximum(d[np.arange(len(R)), k], 1e-300))
    a, b, c = R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]
    e, f, g = R[:, 0, 1] + R[:, 1, 0], R[:, 0, 2] + R[:, 2, 0], R[:, 1, 2] + R[:, 2, 1]
    q = np.empty((len(R), 4))
    # columns: x, y, z, w
    cases = [
        (a, b, c, 0.25 * s * s),  # w largest: (x, y, z) = (a, b, c)/s, w = s/4
        (0.25 * s * s, e, f, a),  # x largest
        (e, 0.25 * s * s, g, b),  # y largest
        (f, g, 0.25 * s * s, c),  # z largest
    ]
    for i, (x, y, z, w) in enumerate(cases):
        sel = k == i
        q[sel] = np.stack([x[sel], y[sel], z[sel], w[sel]], axis=1) / s[sel, None]
    q[q[:, 3] < 0] *= -1.0
    return q


def _ts(t_ns: int) -> Timestamp:
    return Timestamp(int(t_ns) // 1_000_000_000, int(t_ns) % 1_000_000_000)


class RunLog:
    """Writes one run to `path` (MCAP). Thread-safe; every method takes the event time `t_ns`.

    `t_ns` becomes both the MCAP log_time and the messages' `timestamp`. Use one clock for the
    whole run (the executive's); Rerun shows it as a duration when it is small (monotonic or sim
    clock) and as a date when it is a UNIX time.
    """

    def __init__(
        self,
        path: str | Path,
        robot: RobotModel,
        camera: PinholeCamera,
        *,
        bench: bool,
        flush_period_s: float = 0.5,
        overwrite: bool = False,
        jpeg_quality: int = 85,
        chunk_size: int = 256 * 1024,
        metadata: dict[str, str] | None = None,
        images: bool = True,
        image_format: str = "jpeg",
    ) -> None:
        self.path = Path(path)
        self.robot = robot
        self.camera = camera
        self.bench = bench
        self.flush_period_s = float(flush_period_s)
        self.jpeg_quality = int(jpeg_quality)
        self.images = bool(images)  # False (output.images): captures are noted in /log, not stored
        if image_format not in ("jpeg", "png"):
            raise ValueError(f"image_format must be jpeg or png, got {image_format!r}")
        self.image_format = image_format
        self._lock = threading.Lock()
        self._closed = False
        self._dirty = False
        self._static_written = False
        self.n_flushes = 0
        self.call_time_s = 0.0  # wall time spent inside RunLog calls (the logging cost)
        self.write_error: str | None = None  # the first failed write (disk full …): the file ends there
        sink_log = logging.getLogger(SINK_LOGGER)
        if _sink_filter not in sink_log.filters:
            sink_log.addFilter(_sink_filter)

        if (self.path.exists() or self.path.is_symlink()) and not overwrite:
            raise UserError(f"run log already exists: {self.path} (choose another --out directory)")
        if self.path.is_symlink():  # overwrite the link, not what it points at (a planted link)
            self.path.unlink()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        # A private context: our channels never leak into another sink (e.g. a live server).
        self._ctx = Context()
        options = MCAPWriteOptions(
            compression=MCAPCompression.Zstd,
            chunk_size=chunk_size,
            compression_threads=0,  # 2 shared cores: no compressor thread pool
        )
        self._writer = foxglove.open_mcap(self.path, allow_overwrite=overwrite, context=self._ctx, writer_options=options)
        ctx = self._ctx
        self._tf = FrameTransformsChannel(TOPICS["tf"], context=ctx)
        self._image = CompressedImageChannel(TOPICS["image"], context=ctx)
        self._calib = CameraCalibrationChannel(TOPICS["calibration"], context=ctx)
        self._log = LogChannel(TOPICS["log"], context=ctx)
        self._urdf = Channel(TOPICS["robot_description"], schema=_ROS2_STRING, message_encoding="cdr", context=ctx)
        self._meshes = SceneUpdateChannel(TOPICS["robot_meshes"], context=ctx)
        self._link_meshes = link_meshes(robot.urdf_path)  # now (~0.7 s once per process), not in the first log call
        fds = S.descriptor_set_bytes()
        self._proto: dict[str, Channel] = {
            key: Channel(
                TOPICS[key],
                schema=Schema(name=S.full_name(msg), encoding="protobuf", data=fds),
                message_encoding="protobuf",
                context=ctx,
            )
            for key, msg in PROTO_TOPICS.items()
        }
        meta = {"bench": str(bool(bench)).lower(), "urdf": robot.urdf_path.name, "created_unix_ns": str(time.time_ns())}
        meta.update(metadata or {})
        self._writer.write_metadata("capm_run", meta)

        # Frame tree: URDF links by their URDF names (so /robot_description animates), with the
        # URDF root hung under arm_base, and camera/nozzle on the flange link.
        self._urdf_text = robot.urdf_path.read_text()
        parents = urdf_tree(self._urdf_text)
        fk0 = robot.fk(np.zeros(robot.model.nq))
        roots = {p for p in parents.values() if p not in parents}
        self._links = [(ARM_BASE, r) for r in sorted(roots) if r in fk0]
        self._links += [(p, c) for c, p in parents.items() if c in fk0 and p in fk0]
        flange = robot.model.frames[robot.flange_id].name
        self._links += [(flange, CAMERA), (flange, NOZZLE)]
        self._frame_pairs = [(FIELD, BODY), (BODY, ARM_BASE)] + self._links
        self._T_body_base = robot.T_body_base.copy()
        self._height = robot.cfg.body.operating_height

        K = np.asarray(camera.K, dtype=float)
        P = np.c_[K, np.zeros(3)]
        D = [float(v) for v in np.asarray(camera.dist, dtype=float).ravel()]
        self._calib_args = dict(
            frame_id=CAMERA,
            width=int(camera.width),
            height=int(camera.height),
            # ROS / Foxglove names: 5 coefficients plumb_bob (4 padded with k3 = 0), 8 rational_polynomial
            distortion_model="rational_polynomial" if len(D) == 8 else "plumb_bob",
            D=D if len(D) == 8 else (D + [0.0] * 5)[:5],
            K=[float(v) for v in K.ravel()],
            R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            P=[float(v) for v in P.ravel()],
        )

        self._stop = threading.Event()
        self._flusher = threading.Thread(target=self._flush_loop, name="runlog-flush", daemon=True)
        self._flusher.start()
        atexit.register(self.close)  # normal exit, uncaught exception or KeyboardInterrupt

    # ---- plumbing ----------------------------------------------------------------------------
    def __enter__(self) -> "RunLog":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _flush_loop(self) -> None:
        while not self._stop.wait(self.flush_period_s):
            self.flush()

    def flush(self) -> None:
        """Close the open chunk and hand it to the OS (what the background thread does)."""
        with self._lock:
            if self._closed or not self._dirty:
                return
            self._dirty = False
            if self.write_error is not None:
                return
            try:
                self._writer.flush()
            except RuntimeError as e:  # FoxgloveError (disk full …): kept for the run to report
                self._failed(e)
                return
            self.n_flushes += 1

    def _failed(self, e: BaseException) -> None:
        if self.write_error is None:
            self.write_error = " ".join(str(e).split())[:300]

    def _emit(self, t_ns: int, fn) -> None:
        t0 = time.perf_counter()
        with self._lock:
            if self._closed:
                return
            if self.write_error is not None:
                return  # the file ends at the failure: every later write fails too
            _WRITING.log = self
            try:
                if not self._static_written:
                    self._write_static(t_ns)
                fn()
            finally:
                _WRITING.log = None
            self._dirty = True
        self.call_time_s += time.perf_counter() - t0

    def _write_static(self, t_ns: int) -> None:
        # Written at the first message's time so the timeline starts with the run, not at 0.
        self._urdf.log(cdr_string(self._urdf_text), log_time=t_ns)
        self._calib.log(CameraCalibration(timestamp=_ts(t_ns), **self._calib_args), log_time=t_ns)
        self._meshes.log(self._robot_scene(t_ns), log_time=t_ns)
        self._static_written = True

    def _robot_scene(self, t_ns: int) -> SceneUpdate:
        """/robot/meshes: the arm's simplified link meshes (embedded glTF, following each link's
        /tf frame) and a box for the Spot body, for viewers without the URDF's meshes."""
        grey, spot = Color(r=0.78, g=0.8, b=0.82, a=1.0), Color(r=0.95, g=0.75, b=0.1, a=0.6)
        stamp = _ts(t_ns)
        entities = []
        for m in self._link_meshes:
            q = quaternions(m.origin[:3, :3])[0]
            pose = Pose(position=Vector3(x=float(m.origin[0, 3]), y=float(m.origin[1, 3]), z=float(m.origin[2, 3])),
                        orientation=Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])))
            model = ModelPrimitive(pose=pose, scale=Vector3(x=1.0, y=1.0, z=1.0), color=grey, override_color=True,
                                   media_type=GLB_MEDIA_TYPE, data=m.glb)
            entities.append(SceneEntity(timestamp=stamp, frame_id=m.link, id=f"link:{m.link}", frame_locked=True, models=[model]))
        box = CubePrimitive(pose=Pose(position=Vector3(x=0.0, y=0.0, z=-SPOT_BODY_SIZE[2] / 2), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)),
                            size=Vector3(x=SPOT_BODY_SIZE[0], y=SPOT_BODY_SIZE[1], z=SPOT_BODY_SIZE[2]), color=spot)
        entities.append(SceneEntity(timestamp=stamp, frame_id=BODY, id="spot_body", frame_locked=True, cubes=[box]))
        return SceneUpdate(entities=entities)

    def _proto_msg(self, key: str, t_ns: int, **fields):
        m = S.message_class(PROTO_TOPICS[key])(**fields)
        m.timestamp.FromNanoseconds(int(t_ns))
        return m

    def _log_proto(self, key: str, t_ns: int, msg) -> None:
        data = msg.SerializeToString()
        self._emit(t_ns, lambda: self._proto[key].log(data, log_time=int(t_ns)))

    def close(self) -> None:
        """Finalise the file (summary, footer). Idempotent; also runs at interpreter exit. Never
        raises for a failed write: see `write_error` (the file is then readable up to the failure)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._stop.set()
        if self._flusher is not threading.current_thread():
            self._flusher.join(timeout=5.0)
        try:
            self._writer.close()
        except RuntimeError as e:  # a write failed (disk full …): the file holds what came before
            self._failed(e)
        atexit.unregister(self.close)

    @property
    def closed(self) -> bool:
        return self._closed

    # ---- Foxglove-schema topics ----------------------------------------------------------------
    def transforms(self, t_ns: int, body: SE2, q: np.ndarray) -> None:
        """FrameTransforms: field→body→arm_base→URDF links→camera / nozzle, all in one message."""
        t0 = time.perf_counter()
        poses = self.robot.fk(np.asarray(q, dtype=float))
        poses[ARM_BASE] = np.eye(4)
        # One batched pass (not 14 small numpy calls): parent⁻¹·child and quaternions.
        P = np.stack([body.matrix(self._height), self._T_body_base] + [poses[p] for p, _ in self._links])
        C = np.stack([self._T_body_base] + [poses[c] for _, c in self._links])
        R = np.einsum("nji,njk->nik", P[1:, :3, :3], C[:, :3, :3])
        t = np.einsum("nji,nj->ni", P[1:, :3, :3], C[:, :3, 3] - P[1:, :3, 3])
        R = np.concatenate([P[:1, :3, :3], R])
        t = np.concatenate([P[:1, :3, 3], t])
        quats = quaternions(R).tolist()
        ts = _ts(t_ns)
        tfs = [
            FrameTransform(
                timestamp=ts,
                parent_frame_id=parent,
                child_frame_id=child,
                translation=Vector3(x=tr[0], y=tr[1], z=tr[2]),
                rotation=Quaternion(x=qq[0], y=qq[1], z=qq[2], w=qq[3]),
            )
            for (parent, child), tr, qq in zip(self._frame_pairs, t.tolist(), quats)
        ]
        msg = FrameTransforms(transforms=tfs)
        self.call_time_s += time.perf_counter() - t0
        self._emit(t_ns, lambda: self._tf.log(msg, log_time=int(t_ns)))

    def image(self, t_ns: int, bgr: np.ndarray, target_id: str) -> None:
        """CompressedImage (JPEG, or PNG with `image_format`) in frame `camera`, plus CameraCalibration for Pinhole in Rerun
        (with `images` off: only the /log note that an image was taken)."""
        if not self.images:
            h, w = np.shape(bgr)[:2]
            self.event(t_ns, "debug", f"image target={target_id} {w}x{h} (not stored: output.images is false)", name="camera")
            return
        t0 = time.perf_counter()
        if self.image_format == "png":  # lossless; level 1 (a bench frame: 1.2 MB in ~70 ms; level 9 saves 12 % in 10× the time)
            ok, buf = cv2.imencode(".png", np.ascontiguousarray(bgr), [cv2.IMWRITE_PNG_COMPRESSION, 1])
        else:
            ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(bgr), [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            raise ValueError(f"cannot {self.image_format.upper()}-encode an image of shape {np.shape(bgr)}")
        ts = _ts(t_ns)
        img = CompressedImage(timestamp=ts, frame_id=CAMERA, data=buf.tobytes(), format=self.image_format)
        cal = CameraCalibration(timestamp=ts, **self._calib_args)
        h, w = np.shape(bgr)[:2]
        note = Log(timestamp=ts, level=LogLevel.Debug, message=f"image target={target_id} {w}x{h}", name="camera")
        self.call_time_s += time.perf_counter() - t0

        def write() -> None:
            self._image.log(img, log_time=int(t_ns))
            self._calib.log(cal, log_time=int(t_ns))
            self._log.log(note, log_time=int(t_ns))

        self._emit(t_ns, write)

    def event(self, t_ns: int, level: str, message: str, **fields) -> None:
        """A foxglove Log line; `fields` are appended as `key=value` (name: optional `name=`)."""
        if level not in _LEVELS:
            raise ValueError(f"event level {level!r}: choose from {', '.join(_LEVELS)}")
        name = str(fields.pop("name", "mission"))
        text = message + "".join(f" {k}={v}" for k, v in fields.items())
        msg = Log(timestamp=_ts(t_ns), level=_LEVELS[level], message=text, name=name)
        self._emit(t_ns, lambda: self._log.log(msg, log_time=int(t_ns)))

    # ---- protobuf topics -------------------------------------------------------------------------
    def key_state(self, t_ns: int, target_id: str, planner: str, ks: KeyState, note: str = "") -> None:
        m = self._proto_msg("key_state", t_ns, target_id=target_id, planner=planner, note=note)
        _fill_key_state(m, ks)
        self._log_proto("key_state", t_ns, m)

    def plan(self, t_ns: int, target_id: str, plan: Plan) -> None:
        m = self._proto_msg(
            "plan", t_ns, target_id=target_id, planner=plan.planner, p_upper=float(plan.p_upper),
            expected_cost=float(plan.expected_cost), frame_id=FIELD,
        )
        _fill_troi(m.troi, plan.troi)
        _fill_pose(m.start, plan.start)
        _fill_pose(m.end, plan.end)
        if plan.fallback_k3 is not None:
            _fill_pose(m.fallback_k3, plan.fallback_k3)
        for ks in plan.key_states:
            k = m.key_states.add(target_id=target_id, planner=plan.planner)
            k.timestamp.CopyFrom(m.timestamp)
            _fill_key_state(k, ks)
        for name, value in plan.terms.items():
            try:
                m.terms.add(name=str(name), value=float(value))
            except (TypeError, ValueError):
                continue  # non-numeric terms are planner internals; not part of the log contract
        self._log_proto("plan", t_ns, m)

    def detection(
        self,
        t_ns: int,
        target_id: str,
        pixel: tuple[float, float] | None,
        confidence: float,
        reason: str | None,
        mpoi_field: tuple[float, float] | None,
        roi_rim: np.ndarray | None = None,
    ) -> None:
        """One detection attempt; `roi_rim` (n, 2): image pixels of the searched ROI's rim."""
        m = self._proto_msg(
            "detection", t_ns, target_id=target_id, found=pixel is not None, confidence=float(confidence),
            reason=reason or "", frame_id=FIELD,
        )
        if pixel is not None:
            m.pixel.x, m.pixel.y = float(pixel[0]), float(pixel[1])
        if mpoi_field is not None:
            m.mpoi_field.x, m.mpoi_field.y = float(mpoi_field[0]), float(mpoi_field[1])
        if roi_rim is not None:
            for u, v in np.asarray(roi_rim, float).reshape(-1, 2):
                m.roi_rim.add(x=float(u), y=float(v))
        self._log_proto("detection", t_ns, m)

    def regions(
        self,
        t_ns: int,
        target_id: str,
        troi: TROI,
        ro: list[tuple[float, float]],
        rm: list[tuple[float, float]],
        mpoi: tuple[float, float] | None,
    ) -> None:
        """R_o annuli (r_inner, r_outer) around X_w and R_m annuli around the MPOI, field frame."""
        m = self._proto_msg("regions", t_ns, target_id=target_id, frame_id=FIELD)
        _fill_troi(m.troi, troi)
        for a, b in ro:
            m.ro.add(r_inner=float(a), r_outer=float(b))
        for a, b in rm:
            m.rm.add(r_inner=float(a), r_outer=float(b))
        if mpoi is not None:
            m.mpoi.x, m.mpoi.y = float(mpoi[0]), float(mpoi[1])
        self._log_proto("regions", t_ns, m)

    def energy(self, t_ns: int, total: float, target_id: str, target_energy: float, body_moves: int) -> None:
        m = self._proto_msg(
            "energy", t_ns, total=float(total), target_id=target_id, target_energy=float(target_energy), body_moves=int(body_moves)
        )
        self._log_proto("energy", t_ns, m)

    def igniter(
        self,
        t_ns: int,
        flame_on: bool,
        armed: bool,
        fuel: float,
        fault: str | None,
        interlock_ok: bool,
        interlock_reasons: list[str],
        body_stationary: bool,
        epmc_ok: bool,
        estop: bool,
    ) -> None:
        m = self._proto_msg(
            "igniter", t_ns, flame_on=bool(flame_on), armed=bool(armed), fuel=float(fuel), fault=fault or "",
            interlock_ok=bool(interlock_ok), interlock_reasons=[str(r) for r in interlock_reasons],
            body_stationary=bool(body_stationary), epmc_ok=bool(epmc_ok), estop=bool(estop),
        )
        self._log_proto("igniter", t_ns, m)

    def truth_mpoi(self, t_ns: int, target_id: str, xy: tuple[float, float]) -> None:
        """Bench only: the simulated MPOI. Ignored on hardware (there is no ground truth)."""
        if not self.bench:
            return
        m = self._proto_msg("truth_mpoi", t_ns, target_id=target_id, frame_id=FIELD)
        m.mpoi.x, m.mpoi.y = float(xy[0]), float(xy[1])
        self._log_proto("truth_mpoi", t_ns, m)


# ---- helpers ---------------------------------------------------------------------------------
def _fill_pose(m, p: SE2) -> None:
    m.x, m.y, m.yaw = float(p.x), float(p.y), float(p.yaw)


def _fill_troi(m, troi: TROI) -> None:
    m.id, m.x, m.y, m.r = str(troi.id), float(troi.x), float(troi.y), float(troi.r)


def _fill_key_state(m, ks: KeyState) -> None:
    m.label = ks.label
    _fill_pose(m.body, ks.body)
    m.arm = ks.arm or ""
    if ks.target is not None:
        m.target.x, m.target.y = float(ks.target[0]), float(ks.target[1])
    m.radius = float(ks.radius or 0.0)
    m.frame_id = FIELD


class RunLogHandler(logging.Handler):
    """Python log records (WARNING and above) as lines of the run's /log topic, named after their
    logger and with the traceback when there is one: a driver warning or a detector failure
    during a run is kept with the run, where the review finds it, not only on a console."""

    _LEVEL_OF = ((logging.CRITICAL, "fatal"), (logging.ERROR, "error"), (logging.WARNING, "warning"),
                 (logging.INFO, "info"))

    def __init__(self, log: RunLog, now_ns, level: int = logging.WARNING) -> None:
        super().__init__(level)
        self._runlog = log
        self._now_ns = now_ns

    def emit(self, record: logging.LogRecord) -> None:
        if getattr(_WRITING, "log", None) is not None:
            return  # raised by a run log write on this thread (its own failure): cannot go into it
        try:
            text = record.getMessage()
            if record.exc_info:
                text += "\n" + "".join(traceback.format_exception(*record.exc_info)).rstrip()
            level = next((name for lv, name in self._LEVEL_OF if record.levelno >= lv), "debug")
            self._runlog.event(self._now_ns(), level, text, name=record.name)
        except Exception:  # noqa: BLE001 - a log line must never take the run down (logging.Handler idiom)
            self.handleError(record)

