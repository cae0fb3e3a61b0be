"""The bench robot: a DriverSet of simulated body, arm, igniter and camera on one simulated clock,
plus the world truth (the weeds' true MPOIs) — what `drivers: {kind: bench}` in a mission opens.

The world: each TROI of the mission gets a weed whose biological centre (the true MPOI X̄_w) is
drawn from the planner's prior N(X_w, Σ_w), restricted to the TROI disc when `mpoi_in_troi`
(the paper: X̄_w ∈ R_w^TROI by design of the prescan). The camera renders that field from the
arm's actual camera pose (body pose ⊕ arm FK), so the executive sees what the geometry says.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from capm_field.config import TaskConfig
from capm_field.geometry import SE2
from capm_field.keystates import TROI
from capm_field.robot_model import RobotModel
from drivers.interfaces import DriverSet

from .sim_clock import SimClock


@dataclass
class BenchWorld:
    clock: SimClock
    truth: dict[str, tuple[float, float]]
    scene: object
    faults: object | None = None
    transport: str = "inprocess"
    closers: list = field(default_factory=list)  # wire level: the robot sides, closed after the adapters

    def close(self) -> None:  # DriverSet.extras are closed with the set (after the drivers)
        for c in self.closers:
            try:
                c()
            except Exception:  # noqa: BLE001 - close the rest regardless
                pass
        self.closers.clear()


def sample_mpois(trois: list[TROI], task: TaskConfig, seed: int, in_troi: bool) -> dict[str, tuple[float, float]]:
    """True MPOIs: N(X_w, Σ_w) per TROI (restricted to the TROI disc when `in_troi`)."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 7919]))
    out = {}
    for t in trois:
        s = task.sigma(t.r)
        for _ in range(10_000):
            d = rng.normal(scale=s, size=2)
            if not in_troi or math.hypot(*d) <= t.r:
                break
        else:  # pragma: no cover - σ ≫ r_w would need very many draws; fall back to uniform in the disc
            a, rr = rng.uniform(0, 2 * math.pi), t.r * math.sqrt(rng.uniform())
            d = np.array([rr * math.cos(a), rr * math.sin(a)])
        out[t.id] = (float(t.x + d[0]), float(t.y + d[1]))
    return out


def open_bench_drivers(
    robot: RobotModel, task: TaskConfig, trois: list[TROI], start: SE2, seed: int, mpoi_in_troi: bool = True, transport: str = "inprocess"
) -> DriverSet:
    """Bench DriverSet; `extras['world']` holds the clock and the truth.

    transport 'inprocess': simulated drivers on one simulated clock (fast, deterministic).
    transport 'wire': the real adapters — ZenohBody over loopback zenoh to the simulated robot
    side, CanArm/CanIgniter over the python-can virtual bus to the simulated gateway — in real time.
    """
    if transport == "wire":
        return _open_wire(robot, task, trois, start, seed, mpoi_in_troi)
    from .sim_arm import SimArmDriver
    from .sim_body import SimBody, SimBodyDriver
    from .sim_camera import SimCamera
    from .sim_igniter import SimIgniterDriver

    clock = SimClock()
    truth = sample_mpois(trois, task, seed, mpoi_in_troi)
    scene = _scene(trois, truth, start, seed)
    body = SimBodyDriver(SimBody(robot.cfg.body, clock=clock, seed=seed, pose=start))
    arm = SimArmDriver(robot, clock=clock)
    igniter = SimIgniterDriver(clock=clock)

    def camera_pose() -> np.ndarray:
        return robot.T_field_base(body.state().pose) @ arm.state().camera_pose

    camera = SimCamera(scene, camera_pose, robot.cfg.camera, clock_ns=clock.now_ns)
    world = BenchWorld(clock, truth, scene)
    return DriverSet(body, arm, igniter, camera, extras={"world": world})


def _scene(trois: list[TROI], truth: dict, start: SE2, seed: int):
    from .field_scene import FieldScene

    rng = np.random.default_rng(seed)
    kinds = ("rosette", "seedling", "grass", "clover")
    # A prescan TROI of radius r_w comes from a plant seen from above: its longest leaf is drawn in
    # [0.25, 0.55]·r_w (a 1 cm seedling would not have produced a 25 cm TROI).
    weeds = [
        dict(x=truth[t.id][0], y=truth[t.id][1], kind=str(rng.choice(kinds)), size=float(rng.uniform(0.25, 0.55) * t.r), troi_centre=(t.x, t.y), troi_radius=t.r)
        for t in trois
    ]
    xs = [t.x for t in trois] + [start.x]
    ys = [t.y for t in trois] + [start.y]
    return FieldScene.generate(seed, weeds=weeds, area=(min(xs) - 1.5, min(ys) - 1.5, max(xs) + 1.5, max(ys) + 1.5))


def _open_wire(robot: RobotModel, task: TaskConfig, trois: list[TROI], start: SE2, seed: int, mpoi_in_troi: bool) -> DriverSet:
    from drivers.zenoh_body import ZenohBody, ZenohBodyConfig

    from .can_rig import CanBench
    from .sim_camera import SimCamera
    from .zenoh_body_server import free_port, serve_sim_body

    clock = SimClock(realtime=True)  # the robot sides run their own real-time loops
    truth = sample_mpois(trois, task, seed, mpoi_in_troi)
    scene = _scene(trois, truth, start, seed)
    world = BenchWorld(clock, truth, scene, transport="wire")
    port = free_port()
    server = serve_sim_body("bench", [f"tcp/127.0.0.1:{port}"], seed=seed, body=robot.cfg.body, pose=start)
    world.closers.append(server.close)
    try:
        can_bench = CanBench(robot=robot)
        world.closers.insert(0, can_bench.robot_side.close)
        body = ZenohBody(ZenohBodyConfig.loopback(port, "bench"))
    except BaseException:
        world.close()
        raise
    arm, igniter = can_bench.arm, can_bench.igniter

    def camera_pose() -> np.ndarray:
        return robot.T_field_base(body.state().pose) @ arm.state().camera_pose

    camera = SimCamera(scene, camera_pose, robot.cfg.camera, clock_ns=clock.now_ns)
    return DriverSet(body, arm, igniter, camera, extras={"world": world})
