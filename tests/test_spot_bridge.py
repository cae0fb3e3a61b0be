"""Spot bridge translation, checked with the SDK's own protobufs (skipped without bosdyn-client)."""

from __future__ import annotations

import math
import sys

import pytest

from capm_field.config import BodyConfig
from capm_field.geometry import SE2


def test_missing_sdk_is_one_clear_line_and_exit_2(monkeypatch, capsys):
    from drivers import spot_bridge

    monkeypatch.setitem(sys.modules, "bosdyn", None)  # import bosdyn.* now raises ImportError
    monkeypatch.setitem(sys.modules, "bosdyn.client", None)
    assert spot_bridge.main(["--hostname", "spot", "--listen", "tcp/127.0.0.1:7447"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bosdyn-client is not installed" in err[0]


def test_frames_round_trip():
    from drivers.spot_bridge import compose, inverse

    a, b = SE2(1.0, 2.0, 0.7), SE2(-0.3, 0.5, -2.0)
    c = compose(inverse(a), compose(a, b))
    assert c.x == pytest.approx(b.x) and c.y == pytest.approx(b.y) and c.yaw == pytest.approx(b.yaw)


bosdyn = pytest.importorskip("bosdyn.client")


def _robot_state(x: float, y: float, yaw: float, vx: float = 0.0, powered: bool = True, estopped: bool = False):
    from bosdyn.api import geometry_pb2, robot_state_pb2

    rs = robot_state_pb2.RobotState()
    snap = rs.kinematic_state.transforms_snapshot
    snap.child_to_parent_edge_map["odom"].parent_frame_name = ""
    edge = snap.child_to_parent_edge_map["body"]
    edge.parent_frame_name = "odom"
    edge.parent_tform_child.CopyFrom(
        geometry_pb2.SE3Pose(position=geometry_pb2.Vec3(x=x, y=y, z=0.5),
                             rotation=geometry_pb2.Quaternion(w=math.cos(yaw / 2), z=math.sin(yaw / 2)))
    )
    rs.kinematic_state.velocity_of_body_in_odom.linear.x = vx
    rs.power_state.motor_power_state = (robot_state_pb2.PowerState.STATE_ON if powered
                                        else robot_state_pb2.PowerState.STATE_OFF)
    e = rs.estop_states.add(name="hardware_estop")
    e.state = robot_state_pb2.EStopState.STATE_ESTOPPED if estopped else robot_state_pb2.EStopState.STATE_NOT_ESTOPPED
    return rs


def test_move_command_is_an_se2_trajectory_in_odom_with_the_limits():
    from bosdyn.api import robot_command_pb2
    from bosdyn.api.spot import robot_command_pb2 as spot_command_pb2

    from drivers.spot_bridge import move_command

    cfg = BodyConfig(max_speed=0.5, max_yaw_rate=0.6)
    cmd = move_command(SE2(1.0, 0.0, 0.0), SE2(10.0, 20.0, math.pi / 2), cfg)
    assert isinstance(cmd, robot_command_pb2.RobotCommand)
    req = cmd.synchronized_command.mobility_command.se2_trajectory_request
    assert req.se2_frame_name == "odom"
    goal = req.trajectory.points[-1].pose
    # field (1, 0) with the field rotated +90° in odom → odom (10, 21), heading +90°
    assert goal.position.x == pytest.approx(10.0) and goal.position.y == pytest.approx(21.0)
    assert goal.angle == pytest.approx(math.pi / 2)
    params = spot_command_pb2.MobilityParams()
    cmd.synchronized_command.mobility_command.params.Unpack(params)
    assert params.vel_limit.max_vel.linear.x == pytest.approx(0.5)
    assert params.vel_limit.max_vel.angular == pytest.approx(0.6)
    assert params.vel_limit.min_vel.angular == pytest.approx(-0.6)


def test_robot_state_to_body_state():
    from drivers.spot_bridge import body_from_robot_state

    b = body_from_robot_state(_robot_state(10.0, 21.0, math.pi / 2, vx=0.3), SE2(10.0, 20.0, math.pi / 2))
    assert b["pose"].x == pytest.approx(1.0) and b["pose"].y == pytest.approx(0.0, abs=1e-9)
    assert b["pose"].yaw == pytest.approx(0.0, abs=1e-9)
    assert b["moving"] and b["powered"] and not b["estop"]
    b = body_from_robot_state(_robot_state(0, 0, 0, powered=False, estopped=True), SE2(0, 0, 0))
    assert not b["moving"] and not b["powered"] and b["estop"] and b["estop_reason"] == "hardware_estop"


def _feedback(status=None, se2_status=None, body=None, final=None):
    from bosdyn.api import basic_command_pb2 as bc
    from bosdyn.api import robot_command_pb2

    r = robot_command_pb2.RobotCommandFeedbackResponse()
    mob = r.feedback.synchronized_feedback.mobility_command_feedback
    mob.status = status if status is not None else bc.RobotCommandFeedbackStatus.STATUS_PROCESSING
    F = bc.SE2TrajectoryCommand.Feedback
    mob.se2_trajectory_feedback.status = se2_status if se2_status is not None else F.STATUS_GOING_TO_GOAL
    mob.se2_trajectory_feedback.body_movement_status = body if body is not None else F.BODY_STATUS_MOVING
    mob.se2_trajectory_feedback.final_goal_status = final if final is not None else F.FINAL_GOAL_STATUS_ACHIEVABLE
    return r


def test_command_feedback_to_move_status():
    from bosdyn.api import basic_command_pb2 as bc

    from drivers.spot_bridge import move_status_from_feedback

    F, S = bc.SE2TrajectoryCommand.Feedback, bc.RobotCommandFeedbackStatus
    assert move_status_from_feedback(_feedback()) == ("running", None)
    assert move_status_from_feedback(_feedback(se2_status=F.STATUS_AT_GOAL, body=F.BODY_STATUS_MOVING)) == ("running", None)
    assert move_status_from_feedback(_feedback(se2_status=F.STATUS_AT_GOAL, body=F.BODY_STATUS_SETTLED)) == ("succeeded", None)
    assert move_status_from_feedback(_feedback(se2_status=F.STATUS_NEAR_GOAL, body=F.BODY_STATUS_SETTLED,
                                               final=F.FINAL_GOAL_STATUS_BLOCKED)) == ("failed", "blocked")
    assert move_status_from_feedback(_feedback(status=S.STATUS_COMMAND_OVERRIDDEN)) == ("stopped", "overridden")
    assert move_status_from_feedback(_feedback(status=S.STATUS_COMMAND_TIMED_OUT)) == ("timeout", "move_deadline")
    assert move_status_from_feedback(_feedback(status=S.STATUS_ROBOT_FROZEN)) == ("failed", "robot_frozen")


class _FakeCommandClient:
    """Records commands; answers feedback with what the test sets (real protobufs throughout)."""

    def __init__(self) -> None:
        self.sent: list = []
        self.feedback = _feedback()

    def robot_command_async(self, command, end_time_secs=None):
        self.sent.append((command, end_time_secs))
        return len(self.sent)  # an int stands in for the future's result

    def robot_command_feedback(self, cmd_id):
        return self.feedback


class _FakeState:
    def __init__(self) -> None:
        self.rs = _robot_state(0, 0, 0)

    def get_robot_state(self):
        return self.rs


class _FakeEstopKeepAlive:
    def __init__(self) -> None:
        self.calls: list[str] = []

    def allow(self):
        self.calls.append("allow")

    def settle_then_cut(self):
        self.calls.append("settle_then_cut")


def test_spot_backend_drives_the_sdk_behind_the_server_contract():
    import time

    from bosdyn.api import basic_command_pb2 as bc

    from drivers.interfaces import EStopActive
    from drivers.spot_bridge import SpotBackend

    cmd, st, ka = _FakeCommandClient(), _FakeState(), _FakeEstopKeepAlive()
    be = SpotBackend(cmd, st, ka, poll_hz=200)
    try:
        time.sleep(0.05)
        assert be.poll().estop and be.poll().estop_reason == "no_estop_checkin"
        with pytest.raises(EStopActive):
            be.start_move(1, SE2(1, 0, 0), 5.0)
        be.keepalive(True)
        assert ka.calls == ["allow"] and not be.poll().estop
        be.start_move(1, SE2(1, 0, 0), 5.0)
        assert be.poll().move.status == "running"
        sent, end = cmd.sent[-1]
        assert sent.synchronized_command.mobility_command.HasField("se2_trajectory_request")
        assert end == pytest.approx(time.time() + 5.0, abs=1.0)
        F = bc.SE2TrajectoryCommand.Feedback
        st.rs = _robot_state(1.0, 0.0, 0.0)
        cmd.feedback = _feedback(se2_status=F.STATUS_AT_GOAL, body=F.BODY_STATUS_SETTLED)
        deadline = time.monotonic() + 2.0
        while be.poll().move.status == "running" and time.monotonic() < deadline:
            time.sleep(0.01)
        s = be.poll()
        assert s.move.status == "succeeded" and s.move.cmd_id == 1
        assert s.odometry_m == pytest.approx(1.0) and s.moves == 1
        be.keepalive(False)  # check-ins stopped: stop, then Spot settles and cuts power
        assert ka.calls[-1] == "settle_then_cut"
        assert cmd.sent[-1][0].full_body_command.HasField("stop_request")
        assert be.poll().estop and be.poll().estop_reason == "estop_keepalive_timeout"
    finally:
        be.close()
