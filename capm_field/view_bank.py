"""A bank of actual camera poses for multi-TROI views (x_e,k2 serving several TROIs at once).

R_o (reachability.py) answers "can some camera pose from x_b see this one TROI with NSV?". To
see several TROIs in one image the *same* pose must satisfy NSV — coverage and resolution
h ≥ δ — for every disc. The bank holds forward-kinematics camera poses of the Z1 (joint 1 = 0,
joints 2–5 on a grid, a few camera rolls), kept when the arm clears the body and the ground and
the camera looks down. Joint 1 turns the whole arm about the vertical arm axis, so a query turns
each bank pose towards the group of TROIs and checks every disc exactly with
`PinholeCamera.disc_view` plus the body-occlusion test (`RobotModel.disc_occluded`). A pose the
bank returns is a real joint vector q: the executive can command it directly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .arm_poses import ArmSolution
from .camera import PinholeCamera
from .config import TaskConfig
from .geometry import SE2, rot_z, wrap_angle
from .reachability import _joint_grid
from .robot_model import RobotModel

_MIN_LOOK_DOWN = 0.2  # as in reachability: the optical axis points at least this much downwards


@dataclass(frozen=True)
class GroupView:
    """One camera pose from a body pose and which of the queried discs it sees with NSV."""

    q: np.ndarray  # joint angles (joint 1 included)
    T_field_cam: np.ndarray
    seen: np.ndarray  # (k,) bool, per queried disc
    area: np.ndarray  # (k,) h(x_e, disc)

    def solution(self) -> ArmSolution:
        return ArmSolution(self.q, self.T_field_cam, {"seen": self.seen.tolist(), "area_ratio": self.area.tolist()})


class ViewBank:
    """Sampled camera poses (arm-base frame, joint 1 = 0) indexed by where their optical axis meets
    the ground (distance ρ_m from the arm axis, bearing φ_m)."""

    def __init__(self, robot: RobotModel, task: TaskConfig, steps: tuple[int, int, int, int] = (14, 14, 9, 7), rolls: int = 2):
        self.robot = robot
        self.task = task
        self.camera = PinholeCamera.from_config(robot.cfg.camera)
        h = robot.height
        Q = _joint_grid(robot, steps, rolls)
        fk = robot.fk_batch(Q)
        T = fk.camera
        z = T[:, :3, 2]
        c = T[:, :3, 3]
        ok = (-z[:, 2] >= _MIN_LOOK_DOWN) & ~robot.in_keepout(fk.points).any(axis=1) & (c[:, 2] > -h + 0.15)
        Q, T, z, c = Q[ok], T[ok], z[ok], c[ok]
        depth = (-h - c[:, 2]) / z[:, 2]
        g = c + depth[:, None] * z
        rho = np.hypot(g[:, 0], g[:, 1])
        keep = (rho > 0.3) & (rho < 2.0)
        order = np.argsort(rho[keep])
        self.q = Q[keep][order]
        self.T_base_cam = T[keep][order]
        self.rho = rho[keep][order]
        self.phi = np.arctan2(g[keep, 1], g[keep, 0])[order]
        self.q1_lo, self.q1_hi = float(robot.lower[0]), float(robot.upper[0])

    def __len__(self) -> int:
        return len(self.q)

    def best_view(self, body: SE2, centres: np.ndarray, radii: np.ndarray, window: float = 0.25, max_poses: int = 250) -> GroupView | None:
        """The bank pose from body pose x_b that sees the first disc (the primary TROI) with NSV and
        as many of the others as possible (ties: the largest smallest area margin h − δ).

        centres (k, 2) field frame, radii (k,). Candidates: poses whose axis meets the ground
        within `window` of the distance to the group's centre, turned (joint 1) towards it.
        """
        centres = np.atleast_2d(np.asarray(centres, float))
        radii = np.asarray(radii, float).reshape(-1)
        T_fb = self.robot.T_field_base(body)
        inv = np.linalg.inv(T_fb)
        cb = (inv[:2, :2] @ centres.T).T + inv[:2, 3]  # disc centres in the arm-base frame
        aim = cb.mean(axis=0)
        rho_c, bear_c = float(np.hypot(*aim)), float(math.atan2(aim[1], aim[0]))
        i0, i1 = np.searchsorted(self.rho, [rho_c - window, rho_c + window])
        idx = np.arange(i0, i1)
        if len(idx) == 0:
            return None
        if len(idx) > max_poses:  # keep the ones whose axis meets the ground nearest the aim
            idx = idx[np.argsort(np.abs(self.rho[idx] - rho_c), kind="stable")[:max_poses]]
        best = None
        for dq in (0.0, -0.12, 0.12):
            q1 = np.asarray(wrap_angle(bear_c - self.phi[idx] + dq))
            ok = (q1 >= self.q1_lo) & (q1 <= self.q1_hi)
            if not ok.any():
                continue
            j = idx[ok]
            R = np.zeros((len(j), 4, 4))
            R[:, 3, 3] = 1.0
            c1, s1 = np.cos(q1[ok]), np.sin(q1[ok])
            R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c1, -s1, s1, c1, 1.0
            T_bc = R @ self.T_base_cam[j]  # joint 1 turns the arm about the base z axis
            T_fc = T_fb @ T_bc
            cov, area = self.camera.disc_view(T_fc[:, None], centres[None], radii[None])
            seen = cov & (area >= self.task.delta)
            cam_b = T_bc[:, :3, 3]
            h = self.robot.height
            ground_b = np.concatenate([cb, np.full((len(cb), 1), -h)], axis=1)
            cand = seen[:, 0]
            if not cand.any():
                continue
            k = np.flatnonzero(cand)
            shape = (len(k), len(cb))
            occ = self.robot.disc_occluded(
                np.broadcast_to(cam_b[k][:, None, :], shape + (3,)), np.broadcast_to(ground_b[None], shape + (3,)), np.broadcast_to(radii[None], shape)
            )
            seen_k = seen[k] & ~occ
            seen_k &= seen_k[:, :1]
            if not seen_k[:, 0].any():
                continue
            margin = np.where(seen_k, area[k] - self.task.delta, np.inf).min(axis=1)
            score = seen_k.sum(axis=1) + 1e-3 * np.clip(margin, 0, 1)
            m = int(np.argmax(score))
            if best is None or score[m] > best[0]:
                q = self.q[j[k[m]]].copy()
                q[0] = float(q1[ok][k[m]])
                best = (float(score[m]), GroupView(q, T_fc[k[m]], seen_k[m], area[k][m]))
            if best[1].seen.all():
                break
        return None if best is None else best[1]

    def seen_from(self, T_field_cam: np.ndarray, body: SE2, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
        """Which discs satisfy NSV (coverage, h ≥ δ, view rays clear of the body) in one image."""
        centres = np.atleast_2d(np.asarray(centres, float))
        radii = np.asarray(radii, float).reshape(-1)
        if len(centres) == 0:
            return np.zeros(0, bool)
        cov, area = self.camera.disc_view(np.asarray(T_field_cam)[None], centres, radii)
        seen = cov & (area >= self.task.delta)
        T_fb = self.robot.T_field_base(body)
        inv = np.linalg.inv(T_fb)
        cam_b = (inv @ T_field_cam)[:3, 3]
        cb = (inv[:2, :2] @ centres.T).T + inv[:2, 3]
        ground_b = np.concatenate([cb, np.full((len(cb), 1), -self.robot.height)], axis=1)
        if seen.any():
            occ = self.robot.disc_occluded(np.broadcast_to(cam_b, ground_b.shape), ground_b, radii)
            seen &= ~occ
        return seen


def joint1_turn_is_rotation(robot: RobotModel, q: np.ndarray, angle: float) -> float:
    """Max deviation between FK(q with joint 1 + angle) and Rz(angle)·FK(q) (a self-check)."""
    q2 = np.asarray(q, float).copy()
    q2[0] += angle
    a = robot.fk_batch(np.stack([q, q2])).camera
    R = np.eye(4)
    R[:3, :3] = rot_z(angle)
    return float(np.abs(R @ a[0] - a[1]).max())
