"""The arm contract, run against the in-process SimArmDriver and the real CanArm talking to the
wire-level gateway sim over python-can `virtual`. Same tests, same expectations."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import pytest

from capm_field.config import ArmConfig, RobotConfig
from capm_field.robot_model import RobotModel
from drivers.interfaces import Arm, ArmState, DriverTimeout, LinkLost
from sim_bench.sim_arm import ArmPlant, SimArmDriver

STOW = np.array([0.0, 0.0, -0.005, 0.0, 0.0, 0.0])
Q_A = np.array([0.4, 0.9, -1.1, 0.2, 0.3, 0.1])


@pytest.fixture(scope="module")
def robot() -> RobotModel:
    # a brisk arm keeps the real-time (CAN) variant short; both variants use the same limits
    return RobotModel(RobotConfig(arm=ArmConfig(max_joint_speed=3.0)))


@dataclass
class Rig:
    arm: Arm
    plant: ArmPlant
    lose_link: Callable[[], None]
    settle: Callable[[], None]  # let fresh state reach the driver (no-op in process)
    lock: object


class _NoLock:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


@pytest.fixture(params=["inprocess", "can"])
def rig(request, robot):
    if request.param == "inprocess":
        drv = SimArmDriver(robot)

        def lose() -> None:
            drv.hooks.link_lost = True

        yield Rig(drv, drv.plant, lose, lambda: None, _NoLock())
        drv.close()
        return
    from sim_bench.can_rig import CanBench

    # state_timeout 1 s, not 0.25: on a loaded 2-core machine the gateway's thread was starved past
    # 0.25 s mid-move (state_stale, a correct stop). These tests are about the contract; the
    # stale-state stop has its own tests (tests/test_can_protocol.py)
    bench = CanBench(robot=robot, with_igniter=False, heartbeat_timeout=0.3, arm_state_timeout=1.0)
    rs = bench.robot_side

    def lose() -> None:
        rs.faults.bus_off = True
        time.sleep(0.45)  # > heartbeat consumer timeout

    try:
        yield Rig(bench.arm, rs.arm, lose, lambda: time.sleep(0.03), rs.lock)
    finally:
        bench.close()


def test_state_at_rest(rig, robot):
    st = rig.arm.state()
    assert isinstance(st, ArmState)
    assert np.allclose(st.joints, STOW, atol=1e-4)
    assert st.fault is None and not st.moving
    assert np.allclose(st.nozzle_pose, robot.frame_pose(st.joints, "nozzle"), atol=1e-9)
    assert np.allclose(st.camera_pose, robot.frame_pose(st.joints, "camera"), atol=1e-9)


def test_move_joints_arrives(rig):
    r = rig.arm.move_joints(Q_A, timeout=5.0)
    assert r.ok, r
    assert np.allclose(r.final, Q_A, atol=2e-3)
    rig.settle()
    st = rig.arm.state()
    assert np.allclose(st.joints, Q_A, atol=2e-3) and st.fault is None
    # the move respected the speed limit: it took at least max|dq| / vmax
    assert r.extra["duration_s"] >= np.max(np.abs(Q_A - STOW)) / rig.plant.vmax


def test_move_outside_joint_limits_refused(rig):
    q = Q_A.copy()
    q[2] = 0.5  # joint 3 upper limit is 0
    r = rig.arm.move_joints(q, timeout=2.0)
    assert not r.ok and r.reason == "joint_limit"
    assert np.allclose(rig.arm.state().joints, STOW, atol=1e-4)


def test_move_to_pose_nozzle(rig, robot):
    T = robot.frame_pose(Q_A, "nozzle")
    r = rig.arm.move_to_pose("nozzle", T, timeout=5.0)
    assert r.ok, r
    rig.settle()
    assert np.allclose(rig.arm.state().nozzle_pose[:3, 3], T[:3, 3], atol=3e-3)


def test_move_to_unreachable_pose_fails_without_moving(rig):
    T = np.eye(4)
    T[0, 3] = 3.0  # reach is ~0.74 m
    r = rig.arm.move_to_pose("camera", T, timeout=2.0)
    assert not r.ok and r.reason == "ik_failed"
    assert np.allclose(rig.arm.state().joints, STOW, atol=1e-4)


def test_stow_returns_home(rig):
    assert rig.arm.move_joints(Q_A, timeout=5.0).ok
    r = rig.arm.stow(timeout=5.0)
    assert r.ok, r
    assert np.allclose(rig.arm.state().joints, STOW, atol=2e-3)


def test_on_state_reports_the_moves_on_the_way(rig):
    """`on_state` of move_joints and stow gets joint states with rising stamps, from between the
    start and the goal."""
    seen: list[ArmState] = []
    assert rig.arm.move_joints(Q_A, timeout=5.0, on_state=seen.append).ok
    assert len(seen) >= 5
    stamps = [s.stamp_ns for s in seen]
    assert stamps == sorted(stamps)
    frac = [float(np.linalg.norm(np.asarray(s.joints) - STOW) / np.linalg.norm(Q_A - STOW)) for s in seen]
    assert any(0.2 < f < 0.8 for f in frac) and frac[-1] > 0.9
    back: list[ArmState] = []
    assert rig.arm.stow(timeout=5.0, on_state=back.append).ok
    assert len(back) >= 2 and np.allclose(back[-1].joints, STOW, atol=0.05)


def test_timeout_raises_and_stops(rig):
    with pytest.raises(DriverTimeout):
        rig.arm.move_joints(Q_A, timeout=0.2)
    rig.settle()
    q1 = rig.arm.state().joints
    assert not np.allclose(q1, Q_A, atol=1e-2)  # did not carry on to the target
    with rig.lock:
        assert np.allclose(rig.plant.ref, rig.plant.q, atol=1e-3)  # holding where it stopped


def test_fault_mid_move_fails_and_latches_until_reset(rig):
    with rig.lock:
        rig.plant.fault_after_targets = (50, "drive_fault")
    r = rig.arm.move_joints(Q_A, timeout=5.0)
    assert not r.ok and r.reason == "drive_fault"
    rig.settle()
    assert rig.arm.state().fault == "drive_fault"
    r2 = rig.arm.move_joints(STOW, timeout=5.0)
    assert not r2.ok and r2.reason == "drive_fault"
    rig.arm.reset(timeout=1.0)
    rig.settle()
    assert rig.arm.state().fault is None
    assert rig.arm.stow(timeout=5.0).ok


def test_link_loss_raises_link_lost(rig):
    rig.lose_link()
    with pytest.raises(LinkLost):
        rig.arm.move_joints(Q_A, timeout=2.0)
    assert rig.arm.state().fault == "link_lost"


def test_unknown_frame_is_a_programming_error(rig):
    with pytest.raises(ValueError):
        rig.arm.move_to_pose("gripper", np.eye(4), timeout=1.0)


def test_close_is_idempotent_and_final(rig):
    rig.arm.close()
    rig.arm.close()
    with pytest.raises(LinkLost):
        rig.arm.move_joints(STOW, timeout=1.0)
