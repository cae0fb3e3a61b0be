"""Arm key states from a body pose: x_e,k2 (observe the TROI, NSV) and x_e,k3 (flame the MPOI, EPMC).

`ViewSolver` finds joint angles whose camera pose satisfies NSV for a TROI — coverage and target
resolution h ≥ δ via the exact conic projection, view rays clear of the body, arm clear of body
and ground — seeded from the R_o map. `FlameSolver` (reachability.py) does the same for EPMC.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .camera import PinholeCamera
from .config import TaskConfig
from .geometry import SE2
from .reachability import FlameSolver, ReachabilityMaps
from .robot_model import RobotModel


@dataclass(frozen=True)
class ArmSolution:
    q: np.ndarray
    T_field_frame: np.ndarray  # camera (observe) or nozzle (flame) pose in the field frame
    detail: dict


class ViewSolver:
    """x_e,k2: a camera pose from body pose x_b that satisfies 1_NSV(x_e, R_w^TROI)."""

    def __init__(self, robot: RobotModel, maps: ReachabilityMaps, task: TaskConfig):
        self.robot = robot
        self.maps = maps
        self.task = task
        self.camera = PinholeCamera.from_config(robot.cfg.camera)

    def nsv(self, body: SE2, q: np.ndarray, troi_xy: np.ndarray, r: float) -> tuple[bool, float, np.ndarray]:
        """(NSV holds, area ratio h, T_field_cam) for joint angles q from body pose x_b."""
        T_base = self.robot.T_field_base(body)
        T_cam = T_base @ self.robot.frame_pose(q, RobotModel.CAMERA)
        cov, area = self.camera.disc_view(T_cam, np.asarray(troi_xy, float), r)
        ok = bool(cov) and float(area) >= self.task.delta and self.robot.config_valid(q)
        if ok:
            inv = np.linalg.inv(T_base)
            c = inv[:3, :3] @ T_cam[:3, 3] + inv[:3, 3]
            centre = inv[:3, :3] @ np.array([troi_xy[0], troi_xy[1], 0.0]) + inv[:3, 3]
            ok = not bool(self.robot.disc_occluded(c, centre, r))
        return ok, float(area), T_cam

    def solve(self, body: SE2, troi_xy: tuple[float, float], r: float, variant: int = 0) -> ArmSolution | None:
        """A camera pose seeing the TROI with NSV, or None. `variant` > 0 asks for a different
        view (the executive's re-observation from an adjusted pose); if no other view exists the
        last one found is returned."""
        troi_xy = np.asarray(troi_xy, float)
        T_base = self.robot.T_field_base(body)
        inv = np.linalg.inv(T_base)
        tb = inv @ np.array([troi_xy[0], troi_xy[1], 0.0, 1.0])
        dist, bearing = math.hypot(tb[0], tb[1]), math.atan2(tb[1], tb[0])
        seeds: list[tuple[np.ndarray, float]] = []
        for rr in self.maps.bracketing_radii(max(r, float(self.maps.troi_radii[0]))):
            m = self.maps.observe_map(rr)
            for dk in (0, -1, 1, -2, 2, -4, 4, -7, 7, 10):
                s = m.seed_for(dist + dk * m.step, bearing)
                if s is not None and not any(np.array_equal(s[0], x[0]) for x in seeds):
                    seeds.append(s)
        if not seeds:
            return None
        # variant 0: the first NSV pose found; variant k: the k-th one whose camera stands ≥ 3 cm
        # from every earlier one (a genuinely different view for a re-observation).
        found: list[ArmSolution] = []
        for q0, depth in seeds:
            for d in (depth, depth * 0.9, depth * 1.1, depth * 0.8, depth * 1.2):
                q, conv, _ = self.robot.ik_axis_point(RobotModel.CAMERA, tb[:3], d, q0, iters=60, tol=2e-3)
                if not conv:
                    continue
                ok, area, T_cam = self.nsv(body, q, troi_xy, r)
                if not ok or any(np.linalg.norm(T_cam[:3, 3] - f.T_field_frame[:3, 3]) < 0.03 for f in found):
                    continue
                found.append(ArmSolution(q, T_cam, {"depth": d, "area_ratio": area}))
                if len(found) > variant:
                    return found[variant]
        return found[-1] if found else None


def flame_solution(robot: RobotModel, solver: FlameSolver, maps: ReachabilityMaps, body: SE2, mpoi_xy: tuple[float, float]) -> ArmSolution | None:
    """x_e,k3: a nozzle pose from body pose x_b satisfying EPMC for the MPOI (pointing at it), or None."""
    T_base = robot.T_field_base(body)
    tb = np.linalg.inv(T_base) @ np.array([mpoi_xy[0], mpoi_xy[1], 0.0, 1.0])
    dist, bearing = math.hypot(tb[0], tb[1]), math.atan2(tb[1], tb[0])
    extra = []
    s = maps.manip.seed_for(dist, bearing)
    if s is not None:
        extra.append(s[0])
    sol = solver.solve(tb[:3], extra_seeds=extra)
    if sol is None:
        return None
    q, t = sol
    return ArmSolution(q, T_base @ robot.frame_pose(q, RobotModel.NOZZLE), {"flame_distance": t})
