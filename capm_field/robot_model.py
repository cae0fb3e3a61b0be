"""Robot model: Spot body (SE(2) at operating height) + Unitree Z1 arm (URDF, pinocchio) + camera + nozzle.

The Z1 is loaded from the `z1.urdf` shipped in example-robot-data and reduced to its six arm
joints (gripper locked). Camera (hand-eye transform) and flame nozzle are added as pinocchio
operational frames on the flange, so FK, Jacobians and IK all come from pinocchio.
`fk_batch` is a vectorised FK for building reachability maps; it is built from the same
pinocchio joint placements and checked against `pinocchio.framesForwardKinematics` in tests.

Frames: poses returned by `fk*` are in the arm-base frame (Z1 `world`/link00). The arm base
sits at `body.arm_mount` in the body frame, whose origin is at the operating height.
"""

from __future__ import annotations

import importlib.metadata
import math
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import pinocchio as pin

from .config import RobotConfig
from .errors import UserError, not_a_file, shown
from .geometry import SE2, transform_matrix

_URDF_IN_PACKAGE = "cmeel.prefix/share/example-robot-data/robots/z1_description/urdf/z1.urdf"


def default_urdf_path() -> Path:
    """Locate z1.urdf inside the installed example-robot-data distribution."""
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError as e:
        raise UserError("example-robot-data is not installed: it ships the Z1 URDF (pip install example-robot-data)") from e
    return Path(str(dist.locate_file(_URDF_IN_PACKAGE)))


MAX_JOINT_OFFSET_M = 2.0  # a joint this far from its parent is not an arm's (the Z1's: ≤ 0.35 m)


def _axis_rotation(kind: str, q: np.ndarray) -> np.ndarray:
    """Batched rotation matrices (N, 3, 3) about a joint's axis ('RX' | 'RY' | 'RZ')."""
    c, s = np.cos(q), np.sin(q)
    one, zero = np.ones_like(q), np.zeros_like(q)
    if kind.endswith("RX"):
        rows = [[one, zero, zero], [zero, c, -s], [zero, s, c]]
    elif kind.endswith("RY"):
        rows = [[c, zero, s], [zero, one, zero], [-s, zero, c]]
    elif kind.endswith("RZ"):
        rows = [[c, -s, zero], [s, c, zero], [zero, zero, one]]
    else:  # pragma: no cover - the Z1 has only these
        raise ValueError(f"unsupported joint type {kind}")
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


@dataclass(frozen=True)
class BatchFK:
    """Vectorised FK result in the arm-base frame."""

    camera: np.ndarray  # (N, 4, 4) optical frame
    nozzle: np.ndarray  # (N, 4, 4) tool frame, x = flame axis
    points: np.ndarray  # (N, K, 3) points along the arm links, for keep-out / ground checks


MAX_URDF_BYTES = 16 << 20  # the Z1's is 18 kB; meshes are separate files


def _check_xml(urdf: Path) -> None:
    """Malformed XML named with its line and column (urdfdom only says "does not contain a valid
    URDF model" and prints its cause to the process's stderr)."""
    try:
        if urdf.stat().st_size > MAX_URDF_BYTES:
            raise UserError(f"robot.arm.urdf: {urdf}: over {MAX_URDF_BYTES >> 20} MiB, not a robot description")
        ET.parse(urdf)
    except ET.ParseError as e:
        raise UserError(f"robot.arm.urdf: {urdf}: not well-formed XML: {e}") from None
    except OSError as e:
        raise UserError(f"robot.arm.urdf: cannot read {urdf}: {e.strerror or e}") from None


class RobotModel:
    """Kinematics of the whole robot, parameterised by a RobotConfig."""

    CAMERA = "camera"
    NOZZLE = "nozzle"

    def __init__(self, cfg: RobotConfig | None = None):
        self.cfg = cfg or RobotConfig()
        urdf = Path(os.path.expanduser(self.cfg.arm.urdf)) if self.cfg.arm.urdf else default_urdf_path()
        if not urdf.is_file():
            raise UserError(f"robot.arm.urdf: {not_a_file(urdf, 'URDF')}: {urdf}")
        self.urdf_path = urdf
        _check_xml(urdf)
        try:
            full = pin.buildModelFromUrdf(str(urdf))
        except Exception as e:  # pinocchio raises plain exceptions on parse errors
            raise UserError(f"robot.arm.urdf: cannot parse {urdf}: {e}") from e
        lock = [full.getJointId(n) for n in self.cfg.arm.locked_joints if full.existJointName(n)]
        self.model = pin.buildReducedModel(full, lock, pin.neutral(full)) if lock else full
        if self.model.nq != 6:
            unknown = [n for n in self.cfg.arm.locked_joints if not full.existJointName(n)]
            if unknown:  # a misspelt joint left unlocked: name it, not the joint count it causes
                raise UserError(f"robot.arm.locked_joints: no joint named {unknown[0][:80]!r} in {urdf.name} "
                                f"(its joints: {', '.join(list(full.names)[1:])})"[:400])
            raise UserError(f"robot.arm.urdf: expected a 6-joint arm after locking {self.cfg.arm.locked_joints}, got nq={self.model.nq}")
        self._check_joints(urdf)
        flange = self.cfg.arm.flange_frame
        if not self.model.existFrame(flange):
            raise UserError(f"robot.arm.flange_frame: no frame named {flange!r} in {urdf.name}")
        self.flange_id = self.model.getFrameId(flange, pin.FrameType.BODY)
        fl = self.model.frames[self.flange_id]
        for name, tf in ((self.CAMERA, self.cfg.camera.hand_eye), (self.NOZZLE, self.cfg.nozzle.tool)):
            placement = fl.placement * pin.SE3(transform_matrix(tf))
            self.model.addFrame(pin.Frame(name, fl.parentJoint, self.flange_id, placement, pin.FrameType.OP_FRAME))
        self.camera_id = self.model.getFrameId(self.CAMERA)
        self.nozzle_id = self.model.getFrameId(self.NOZZLE)
        self.data = self.model.createData()
        self.lower = self.model.lowerPositionLimit.copy()
        self.upper = self.model.upperPositionLimit.copy()
        stow = np.asarray(self.cfg.arm.stow_joints, float)
        bad = [i + 1 for i in range(len(stow)) if not self.lower[i] - 1e-3 <= stow[i] <= self.upper[i] + 1e-3]
        if bad:  # the gateway would refuse to go there (TARGET_OUT_OF_RANGE): every stow would fail
            raise UserError(f"robot.arm.stow_joints: joint(s) {bad} outside the limits of {urdf.name} "
                            f"({', '.join(f'J{i}: [{self.lower[i - 1]:.4f}, {self.upper[i - 1]:.4f}]' for i in bad)} rad)")
        self.joint_names = [self.model.names[i] for i in range(1, self.model.njoints)]
        self.T_body_base = transform_matrix(self.cfg.body.arm_mount)
        self.T_body_base[2, 3] += 0.0  # body origin is already at operating height

    def _check_joints(self, urdf: Path) -> None:
        """What the kinematics here can use: revolute joints about a frame axis (the batched FK,
        `_axis_rotation`; the Z1's are), and finite joint offsets of arm size. A URDF off either
        (a tilted axis, an origin in millimetres) failed later as a traceback in `regions` and
        `bench`, or with all areas 0 and no word (found by a fuzzing sweep)."""
        for j in range(1, self.model.njoints):
            name, kind = self.model.names[j], self.model.joints[j].shortname()
            if kind not in ("JointModelRX", "JointModelRY", "JointModelRZ"):
                raise UserError(f"robot.arm.urdf: joint {name!r} of {urdf.name} is {kind.removeprefix('JointModel')}: "
                                "only revolute joints about the x, y or z axis of their frame are supported")
            d = math.hypot(*self.model.jointPlacements[j].translation)  # (no overflow: 1e300 stays 1e300)
            if not d <= MAX_JOINT_OFFSET_M:  # (NaN too)
                raise UserError(f"robot.arm.urdf: joint {name!r} of {urdf.name} sits {shown(d)} m from "
                                f"its parent (limit {MAX_JOINT_OFFSET_M} m: URDF lengths are in metres)")

    # ---- frames --------------------------------------------------------------------------
    @property
    def height(self) -> float:
        """Height of the arm base above the ground (m)."""
        return self.cfg.body.operating_height + float(self.T_body_base[2, 3])

    def T_field_base(self, body: SE2) -> np.ndarray:
        """Arm base in the field frame for body pose x_b."""
        return body.matrix(self.cfg.body.operating_height) @ self.T_body_base

    def arm_base_xy(self, body: SE2) -> np.ndarray:
        return self.T_field_base(body)[:2, 3]

    def body_for_arm_base(self, base_xy: np.ndarray, yaw: float) -> SE2:
        """The body pose whose arm base stands at `base_xy` with heading `yaw`."""
        off = self.T_body_base[:2, 3]
        c, s = math.cos(yaw), math.sin(yaw)
        return SE2(float(base_xy[0] - (c * off[0] - s * off[1])), float(base_xy[1] - (s * off[0] + c * off[1])), yaw)

    # ---- forward kinematics ----------------------------------------------------------------
    def fk(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """Poses (4×4, arm-base frame) of every link frame plus 'camera' and 'nozzle'."""
        q = np.asarray(q, dtype=float)
        pin.framesForwardKinematics(self.model, self.data, q)
        out = {}
        for i, f in enumerate(self.model.frames):
            if f.type in (pin.FrameType.BODY, pin.FrameType.OP_FRAME):
                out[f.name] = self.data.oMf[i].homogeneous.copy()
        return out

    def frame_pose(self, q: np.ndarray, frame: str) -> np.ndarray:
        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        return self.data.oMf[self.model.getFrameId(frame)].homogeneous.copy()

    @cached_property
    def _chain(self) -> list[tuple[str, np.ndarray]]:
        return [(self.model.joints[j].shortname(), self.model.jointPlacements[j].homogeneous) for j in range(1, self.model.njoints)]

    def fk_batch(self, Q: np.ndarray) -> BatchFK:
        """Vectorised FK for joint configurations Q (N, 6): camera, nozzle and link points."""
        Q = np.asarray(Q, dtype=float)
        n = len(Q)
        T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
        pts = []
        prev = np.zeros((n, 3))
        for j, (kind, placement) in enumerate(self._chain):
            T = T @ placement
            R = np.eye(4)[None].repeat(n, 0)
            R[:, :3, :3] = _axis_rotation(kind, Q[:, j])
            T = T @ R
            p = T[:, :3, 3]
            for a in (0.5,):  # midpoint of each link, then the joint itself
                pts.append(prev + a * (p - prev))
            pts.append(p)
            prev = p
        fl = self.model.frames[self.flange_id].placement.homogeneous
        Tf = T @ fl
        cam = Tf @ transform_matrix(self.cfg.camera.hand_eye)
        noz = Tf @ transform_matrix(self.cfg.nozzle.tool)
        for P in (Tf[:, :3, 3], cam[:, :3, 3], noz[:, :3, 3]):
            pts.append(prev + 0.5 * (P - prev))
            pts.append(P)
        return BatchFK(camera=cam, nozzle=noz, points=np.stack(pts, axis=1))

    # ---- body keep-out and ground ----------------------------------------------------------
    @property
    def keepout_depth(self) -> float:
        d = self.cfg.body.keepout_depth
        return self.height if d is None else min(d, self.height)

    def in_keepout(self, p_base: np.ndarray) -> np.ndarray:
        """Points (…, 3) in the arm-base frame inside the body keep-out cylinder or below ground clearance."""
        b = self.cfg.body
        r = np.hypot(p_base[..., 0], p_base[..., 1])
        body = (r < b.keepout_radius) & (p_base[..., 2] < 0.0) & (p_base[..., 2] > -self.keepout_depth)
        ground = p_base[..., 2] < -self.height + self.cfg.arm.min_clearance
        return body | ground

    def segment_blocked(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Whether segments a→b (…, 3) in the arm-base frame pass through the body keep-out cylinder.

        Exact: clip the segment to the cylinder's z-slab, then test the clipped piece's distance
        to the axis in the xy plane. Used for camera view rays and the flame ray (occlusion).
        """
        a = np.asarray(a, dtype=float)
        b = np.asarray(b, dtype=float)
        bc = self.cfg.body
        d = b - a
        dz = d[..., 2]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # subnormal dz: ±inf is right
            t1 = np.where(dz != 0, (0.0 - a[..., 2]) / dz, -np.inf)
            t2 = np.where(dz != 0, (-self.keepout_depth - a[..., 2]) / dz, np.inf)
        flat_inside = (dz == 0) & (a[..., 2] < 0.0) & (a[..., 2] > -self.keepout_depth)
        tlo = np.where(dz == 0, np.where(flat_inside, 0.0, 1.0), np.maximum(0.0, np.minimum(t1, t2)))
        thi = np.where(dz == 0, np.where(flat_inside, 1.0, 0.0), np.minimum(1.0, np.maximum(t1, t2)))
        dxy = d[..., :2]
        axy = a[..., :2]
        n2 = np.einsum("...i,...i->...", dxy, dxy)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            ts = np.where(n2 > 0, -np.einsum("...i,...i->...", axy, dxy) / n2, tlo)
        ts = np.clip(ts, tlo, np.maximum(tlo, thi))
        closest = axy + ts[..., None] * dxy
        return (tlo <= thi) & (np.hypot(closest[..., 0], closest[..., 1]) < bc.keepout_radius)

    RING_POINTS = 16  # boundary samples of a TROI disc for the view-occlusion test

    def disc_occluded(self, cam_base: np.ndarray, centre_base: np.ndarray, r: np.ndarray | float) -> np.ndarray:
        """Whether any view ray from camera position(s) (…, 3) to the boundary of the ground disc
        (centre (…, 3) on the ground, radius r), all in the arm-base frame, passes through the body."""
        ang = np.linspace(0.0, 2 * np.pi, self.RING_POINTS, endpoint=False)
        ring = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], axis=1)  # (k, 3)
        centre = np.asarray(centre_base, dtype=float)[..., None, :]
        pts = centre + np.asarray(r, dtype=float)[..., None, None] * ring
        cam = np.broadcast_to(np.asarray(cam_base, dtype=float)[..., None, :], pts.shape)
        return self.segment_blocked(cam, pts).any(axis=-1)

    def config_valid(self, q: np.ndarray) -> bool:
        """Joint limits hold and no arm point enters the keep-out volume or the ground."""
        q = np.asarray(q, dtype=float)
        if np.any(q < self.lower - 1e-9) or np.any(q > self.upper + 1e-9):
            return False
        return not bool(self.in_keepout(self.fk_batch(q[None]).points[0]).any())

    # ---- inverse kinematics ----------------------------------------------------------------
    def ik_axis_point(
        self,
        frame: str,
        target_base: np.ndarray,
        distance: float,
        q_seed: np.ndarray,
        iters: int = 80,
        tol: float = 1e-4,
        damping: float = 1e-4,
    ) -> tuple[np.ndarray, bool, float]:
        """IK: put the point at `distance` along `frame`'s pointing axis onto `target_base`.

        The pointing axis is +x for the nozzle (flame direction) and +z for the camera (optical
        axis). Roll about the axis stays free (redundancy resolved by damped least squares).
        Joint limits are enforced by clamping each step. Returns (q, converged, residual m).
        """
        fid = self.model.getFrameId(frame)
        col = 0 if frame == self.NOZZLE else 2
        q = np.clip(np.asarray(q_seed, dtype=float).copy(), self.lower, self.upper)
        target = np.asarray(target_base, dtype=float)
        err = np.inf
        for _ in range(iters):
            pin.framesForwardKinematics(self.model, self.data, q)
            M = self.data.oMf[fid]
            a = M.rotation[:, col]
            e = M.translation + distance * a - target
            err = float(np.linalg.norm(e))
            if err < tol:
                return q, True, err
            J = pin.computeFrameJacobian(self.model, self.data, q, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            Jv, Jw = J[:3], J[3:]
            # d(p + s·a)/dq = Jv + s·(ω × a) = Jv − s·[a]× Jw
            ax = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
            Jt = Jv - distance * ax @ Jw
            dq = Jt.T @ np.linalg.solve(Jt @ Jt.T + damping * np.eye(3), -e)
            q = np.clip(q + dq, self.lower, self.upper)
        return q, err < tol, err

    def ik_pose(self, frame: str, T_target_base: np.ndarray, q_seed: np.ndarray, iters: int = 100, tol: float = 1e-4) -> tuple[np.ndarray, bool, float]:
        """Full 6-D IK of `frame` to a pose in the arm-base frame (pinocchio log6 error, clamped DLS)."""
        fid = self.model.getFrameId(frame)
        target = pin.SE3(np.asarray(T_target_base, dtype=float))
        q = np.clip(np.asarray(q_seed, dtype=float).copy(), self.lower, self.upper)
        err = np.inf
        for _ in range(iters):
            pin.framesForwardKinematics(self.model, self.data, q)
            dM = target.actInv(self.data.oMf[fid])
            e = pin.log6(dM).vector
            err = float(np.linalg.norm(e))
            if err < tol:
                return q, True, err
            J = pin.computeFrameJacobian(self.model, self.data, q, fid, pin.ReferenceFrame.LOCAL)
            J = pin.Jlog6(dM) @ J
            dq = -J.T @ np.linalg.solve(J @ J.T + 1e-6 * np.eye(6), e)
            q = np.clip(q + dq, self.lower, self.upper)
        return q, err < tol, err
