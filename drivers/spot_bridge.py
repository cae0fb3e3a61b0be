"""On-robot bridge: serves the zenoh body protocol on Spot's payload computer, drives the Spot SDK.

    capm-field spot-bridge --hostname 192.168.80.3 --listen tcp/192.168.50.5:7447

The protocol side is `drivers.body_server.BodyServer` (the same code the bench runs); this
module is the `SpotBackend` behind it plus pure translation functions (goal → RobotCommand,
RobotState → body state, command feedback → move status), tested with the SDK's own
protobufs. bosdyn-client is the optional extra `[spot]`, imported only here and lazily.

Mapping to Spot's own safety model: the bridge holds the body lease with `LeaseKeepAlive` and
an E-stop endpoint with `EstopKeepAlive`. The protocol's E-stop check-ins gate the bridge's:
when the commander (the lease holder) stops checking in, or a client engages the E-stop, the
bridge stops the body and lets Spot settle and cut motor power (`settle_then_cut`); the
server allows again on a fresh check-in once every engage is released (power on via `cmd/power`).
Field frame = Spot's odom frame moved by `--field-in-odom x,y,yaw` (where the field origin
sits in odom when the bridge starts; a registration step is outside this bridge).
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import signal
import sys
import threading
import time
from typing import Any

from capm_field.config import BodyConfig
from capm_field.geometry import FIELD_EXTENT_M, SE2, wrap_angle
from drivers.body_protocol import LinkConfig, check_id, link_security, zenoh_error_text
from drivers.body_server import BackendState, BodyBackend, BodyServer, MoveStatus, ServerConfig, check_link_security
from drivers.interfaces import EStopActive

log = logging.getLogger(__name__)
MOVING_SPEED = 0.02  # m/s or rad/s: below this (odom velocity) the body counts as standing still


# ---- frames -----------------------------------------------------------------------------------
def compose(a: SE2, b: SE2) -> SE2:
    """a ∘ b: pose b expressed in a's parent frame."""
    c, s = math.cos(a.yaw), math.sin(a.yaw)
    return SE2(a.x + c * b.x - s * b.y, a.y + s * b.x + c * b.y, float(wrap_angle(a.yaw + b.yaw)))


def inverse(a: SE2) -> SE2:
    c, s = math.cos(a.yaw), math.sin(a.yaw)
    return SE2(-(c * a.x + s * a.y), -(-s * a.x + c * a.y), float(wrap_angle(-a.yaw)))


# ---- translation (pure: SDK protobufs in and out) ------------------------------------------------
def mobility_params(cfg: BodyConfig):
    """Spot MobilityParams carrying the body's speed and yaw-rate limits."""
    from bosdyn.api import geometry_pb2
    from bosdyn.api.spot import robot_command_pb2 as spot_command_pb2

    v = geometry_pb2.SE2Velocity(linear=geometry_pb2.Vec2(x=cfg.max_speed, y=cfg.max_speed), angular=cfg.max_yaw_rate)
    vmin = geometry_pb2.SE2Velocity(linear=geometry_pb2.Vec2(x=-cfg.max_speed, y=-cfg.max_speed), angular=-cfg.max_yaw_rate)
    return spot_command_pb2.MobilityParams(vel_limit=geometry_pb2.SE2VelocityLimit(max_vel=v, min_vel=vmin))


def move_command(goal_field: SE2, field_in_odom: SE2, cfg: BodyConfig, frame_name: str | None = None):
    """RobotCommand walking the body to `goal_field` (field frame), expressed in odom."""
    from bosdyn.client.frame_helpers import ODOM_FRAME_NAME
    from bosdyn.client.robot_command import RobotCommandBuilder

    g = compose(field_in_odom, goal_field)
    return RobotCommandBuilder.synchro_se2_trajectory_point_command(
        goal_x=g.x, goal_y=g.y, goal_heading=g.yaw, frame_name=frame_name or ODOM_FRAME_NAME,
        params=mobility_params(cfg),
    )


def body_from_robot_state(robot_state, field_in_odom: SE2) -> dict[str, Any]:
    """pose (field frame), moving, powered, estop, estop_reason from a RobotState."""
    from bosdyn.api import robot_state_pb2
    from bosdyn.client.frame_helpers import BODY_FRAME_NAME, ODOM_FRAME_NAME, get_se2_a_tform_b

    ks = robot_state.kinematic_state
    p = get_se2_a_tform_b(ks.transforms_snapshot, ODOM_FRAME_NAME, BODY_FRAME_NAME)
    pose = compose(inverse(field_in_odom), SE2(p.x, p.y, p.angle))
    v = ks.velocity_of_body_in_odom
    speed = math.hypot(v.linear.x, v.linear.y)
    stopped = [e.name for e in robot_state.estop_states if e.state == robot_state_pb2.EStopState.STATE_ESTOPPED]
    return {
        "pose": pose,
        "moving": speed > MOVING_SPEED or abs(v.angular.z) > MOVING_SPEED,
        "powered": robot_state.power_state.motor_power_state == robot_state_pb2.PowerState.STATE_ON,
        "estop": bool(stopped),
        "estop_reason": ", ".join(sorted(stopped)) or None,
    }


def move_status_from_feedback(response) -> tuple[str, str | None]:
    """('running'|'succeeded'|'failed'|'stopped'|'timeout', reason) from RobotCommandFeedbackResponse."""
    from bosdyn.api import basic_command_pb2 as bc

    mob = response.feedback.synchronized_feedback.mobility_command_feedback
    fs = bc.RobotCommandFeedbackStatus
    if mob.status == fs.STATUS_COMMAND_OVERRIDDEN:
        return "stopped", "overridden"
    if mob.status == fs.STATUS_COMMAND_TIMED_OUT:
        return "timeout", "move_deadline"
    if mob.status == fs.STATUS_ROBOT_FROZEN:
        return "failed", "robot_frozen"
    if mob.status != fs.STATUS_PROCESSING:
        return "failed", fs.Status.Name(mob.status).lower()
    fb = mob.se2_trajectory_feedback
    F = bc.SE2TrajectoryCommand.Feedback
    settled = fb.body_movement_status == F.BODY_STATUS_SETTLED
    if fb.status == F.STATUS_AT_GOAL and settled:
        return "succeeded", None
    if settled and fb.final_goal_status == F.FINAL_GOAL_STATUS_BLOCKED:
        return "failed", "blocked"
    return "running", None


# ---- backend --------------------------------------------------------------------------------------
class SpotBackend(BodyBackend):
    """Spot behind the body server. SDK calls run on the poller thread or as async RPCs, never
    under the server lock for long. Clients are passed in (tests hand in fakes)."""

    def __init__(self, command_client, state_client, estop_keepalive, robot=None,
                 config: BodyConfig | None = None, field_in_odom: SE2 = SE2(0.0, 0.0, 0.0), poll_hz: float = 50.0) -> None:
        self.cmd, self.state_client, self.estop_ka, self.robot = command_client, state_client, estop_keepalive, robot
        self.config = config or BodyConfig()
        self.field_in_odom = field_in_odom
        self._lock = threading.Lock()
        self._body: dict[str, Any] | None = None
        self._odometry = 0.0
        self._moves = 0
        self._move: MoveStatus | None = None
        self._spot_cmd: Any = None  # future or int id of the active Spot command
        self._ka_engaged: str | None = "no_estop_checkin"
        self._stop_evt = threading.Event()
        self._period = 1.0 / poll_hz
        self._thread = threading.Thread(target=self._poll_loop, name="spot-poller", daemon=True)
        self._thread.start()

    def poll(self) -> BackendState:
        with self._lock:
            b = self._body
            if b is None:
                return BackendState(SE2(0.0, 0.0, 0.0), False, False, True, "no_robot_state", 0.0, 0, "no_robot_state")
            estop = b["estop"] or self._ka_engaged is not None
            reasons = [r for r in (b["estop_reason"], self._ka_engaged) if r]
            return BackendState(b["pose"], b["moving"], b["powered"], estop, ", ".join(reasons) or None,
                                self._odometry, self._moves, None, self._move)

    def start_move(self, cmd_id: int, goal: SE2, timeout_s: float) -> None:
        with self._lock:
            if self._ka_engaged or (self._body and self._body["estop"]):
                raise EStopActive(f"E-stop engaged ({self._ka_engaged or self._body['estop_reason']})")
            if self._move is not None and not self._move.done:
                self._move = MoveStatus(self._move.cmd_id, "stopped", "preempted", self._body and self._body["pose"])
            self._moves += 1
            if self._body is not None and not self._body["powered"]:
                self._move = MoveStatus(cmd_id, "failed", "not_powered", self._body["pose"])
                return
            self._move = MoveStatus(cmd_id, "running")
        # end_time bounds the move on the robot itself, whatever happens to us (needs time sync).
        self._spot_cmd = self.cmd.robot_command_async(
            move_command(goal, self.field_in_odom, self.config), end_time_secs=time.time() + timeout_s
        )

    def stop(self, reason: str) -> None:
        from bosdyn.client.robot_command import RobotCommandBuilder

        self.cmd.robot_command_async(RobotCommandBuilder.stop_command())
        with self._lock:
            if self._move is not None and not self._move.done:
                self._move = MoveStatus(self._move.cmd_id, "stopped", reason, self._body and self._body["pose"])
            self._spot_cmd = None

    def set_power(self, on: bool) -> None:
        if self.robot is None:
            return
        # power_on blocks for seconds: run it off the server lock.
        target = (lambda: self.robot.power_on(timeout_sec=20)) if on else (lambda: self.robot.power_off(cut_immediately=False))
        threading.Thread(target=target, name="spot-power", daemon=True).start()

    def keepalive(self, ok: bool, reason: str = "estop_keepalive_timeout") -> None:
        if ok:
            self._ka_engaged = None
            self.estop_ka.allow()
        else:
            self._ka_engaged = reason
            self.stop(reason)
            self.estop_ka.settle_then_cut()

    def close(self) -> None:
        self._stop_evt.set()
        self._thread.join(timeout=2.0)

    def _poll_loop(self) -> None:
        last: SE2 | None = None
        while not self._stop_evt.wait(self._period):
            try:
                body = body_from_robot_state(self.state_client.get_robot_state(), self.field_in_odom)
                status = None
                spot_cmd = self._spot_cmd
                if spot_cmd is not None and self._move is not None and not self._move.done:
                    cmd_id = spot_cmd.result() if hasattr(spot_cmd, "result") else spot_cmd
                    self._spot_cmd = cmd_id
                    status = move_status_from_feedback(self.cmd.robot_command_feedback(cmd_id))
                with self._lock:
                    self._body = body
                    if last is not None:
                        self._odometry += last.distance(body["pose"])
                    last = body["pose"]
                    if status is not None and status[0] != "running" and self._move is not None and not self._move.done:
                        self._move = MoveStatus(self._move.cmd_id, status[0], status[1], body["pose"])
            except Exception:  # noqa: BLE001 - keep polling; the state stream shows staleness
                log.exception("spot poll failed")
                with self._lock:
                    if self._move is not None and not self._move.done and self._spot_cmd is not None:
                        self._move = MoveStatus(self._move.cmd_id, "failed", "spot_command_error", last)
                        self._spot_cmd = None


class SpotUnavailable(Exception):
    """Spot could not be taken (no credentials, unreachable, login refused, lease held): one line."""

    def __init__(self, msg: str, exit_code: int = 1) -> None:
        super().__init__(msg)
        self.exit_code = exit_code


def connect_spot(hostname: str, config: BodyConfig, field_in_odom: SE2, estop_timeout_s: float):
    """Log in, take the lease and an E-stop endpoint, power on and stand. Returns (backend, cleanup);
    SpotUnavailable when that fails."""
    if not (os.environ.get("BOSDYN_CLIENT_USERNAME") and os.environ.get("BOSDYN_CLIENT_PASSWORD")) and not sys.stdin.isatty():
        # the SDK would prompt for them, then fail with a traceback
        raise SpotUnavailable("BOSDYN_CLIENT_USERNAME and BOSDYN_CLIENT_PASSWORD must be set (no terminal to ask on)", 2)
    try:
        return _connect_spot(hostname, config, field_in_odom, estop_timeout_s)
    except Exception as e:  # noqa: BLE001 - bosdyn's errors: unreachable, refused login, lease held, E-stopped
        raise SpotUnavailable(f"cannot take Spot at {hostname}: {type(e).__name__}: {' '.join(str(e).split())[:300]}") from e


def _connect_spot(hostname: str, config: BodyConfig, field_in_odom: SE2, estop_timeout_s: float):
    import bosdyn.client
    import bosdyn.client.util
    from bosdyn.client.estop import EstopClient, EstopEndpoint, EstopKeepAlive
    from bosdyn.client.lease import LeaseClient, LeaseKeepAlive
    from bosdyn.client.robot_command import RobotCommandClient, blocking_stand
    from bosdyn.client.robot_state import RobotStateClient

    sdk = bosdyn.client.create_standard_sdk("capm-spot-bridge")
    robot = sdk.create_robot(hostname)
    bosdyn.client.util.authenticate(robot)  # BOSDYN_CLIENT_USERNAME / _PASSWORD, as every SDK example
    robot.time_sync.wait_for_sync()
    estop_ep = EstopEndpoint(robot.ensure_client(EstopClient.default_service_name), "capm-bridge", estop_timeout_s)
    estop_ep.force_simple_setup()
    estop_ka = EstopKeepAlive(estop_ep)
    lease_ka = LeaseKeepAlive(robot.ensure_client(LeaseClient.default_service_name), must_acquire=True, return_at_exit=True)
    command_client = robot.ensure_client(RobotCommandClient.default_service_name)
    robot.power_on(timeout_sec=20)
    blocking_stand(command_client, timeout_sec=10)
    backend = SpotBackend(command_client, robot.ensure_client(RobotStateClient.default_service_name), estop_ka,
                          robot=robot, config=config, field_in_odom=field_in_odom)

    def cleanup() -> None:
        backend.close()
        try:
            robot.power_off(cut_immediately=False)  # sits down first
        finally:
            lease_ka.shutdown()
            estop_ka.shutdown()

    return backend, cleanup


def _se2(text: str) -> SE2:
    try:
        x, y, yaw = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected x,y,yaw (m, m, rad), got {text!r}") from None
    if not (abs(x) <= FIELD_EXTENT_M and abs(y) <= FIELD_EXTENT_M and math.isfinite(yaw)):  # NaN fails too
        raise argparse.ArgumentTypeError(f"x,y,yaw must be finite, x and y within ±{FIELD_EXTENT_M:g} m, got {text[:80]!r}")
    return SE2(x, y, yaw)


def _check_args(a: argparse.Namespace) -> str | None:
    """Why the options cannot serve a body (one line), checked before the SDK touches the robot."""
    try:
        check_id("robot_id", a.robot_id)
    except ValueError as e:
        return f"--robot-id: {e}"
    if not a.hostname.strip():
        return "--hostname: empty"
    # lower bounds: a keep-alive or lease shorter than a network round trip and a few state periods
    # (1e-300 s passed) E-stops or expires at once, which is safe but serves nothing
    for opt, v, lo, hi in (("--estop-timeout", a.estop_timeout, 0.1, 60.0), ("--spot-estop-timeout", a.spot_estop_timeout, 1.0, 600.0),
                           ("--lease-ttl", a.lease_ttl, 0.1, 600.0), ("--lease-ms", a.lease_ms, 100, 60_000)):
        if not lo <= v <= hi:  # NaN too
            return f"{opt} must be in [{lo:g}, {hi:g}], got {v}"
    try:
        BodyConfig(max_speed=a.max_speed, max_yaw_rate=a.max_yaw_rate)
    except ValueError as e:  # pydantic's ValidationError: its first error, one line
        err = e.errors()[0] if hasattr(e, "errors") else {"loc": (), "msg": str(e)}
        return f"--{'-'.join(str(x) for x in err['loc']).replace('_', '-')}: {err['msg']} (got {err.get('input')!r})"
    return None


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="capm-field spot-bridge", description=__doc__.splitlines()[0])
    ap.add_argument("--hostname", required=True, help="Spot's address as seen from the payload computer")
    ap.add_argument("--listen", action="append", required=True, help="zenoh endpoint to serve on (repeatable)")
    ap.add_argument("--connect", action="append", default=[], help="zenoh endpoint to connect to (repeatable)")
    ap.add_argument("--robot-id", default="spot", help="key prefix capm/<robot-id>/body")
    ap.add_argument("--zenoh-config", help="zenoh JSON5 config: mutual TLS, user/password, access control "
                                           "(mission/examples/zenoh-robot.json5, docs/security.md); endpoints still apply")
    ap.add_argument("--insecure", action="store_true",
                    help="serve a non-loopback endpoint without authentication + ACL (anyone on the network can "
                         "command the body: lab use only)")
    ap.add_argument("--lease-ms", type=int, default=1000, help="zenoh transport lease (ms)")
    ap.add_argument("--estop-timeout", type=float, default=1.0, help="protocol E-stop keep-alive timeout (s)")
    ap.add_argument("--spot-estop-timeout", type=float, default=9.0, help="Spot E-stop endpoint timeout (s)")
    ap.add_argument("--lease-ttl", type=float, default=2.0, help="protocol body lease TTL (s)")
    ap.add_argument("--field-in-odom", type=_se2, default=SE2(0.0, 0.0, 0.0), help="field origin in odom: x,y,yaw")
    ap.add_argument("--max-speed", type=float, default=BodyConfig().max_speed)
    ap.add_argument("--max-yaw-rate", type=float, default=BodyConfig().max_yaw_rate)
    a = ap.parse_args(argv)
    bad = _check_args(a)
    if bad:
        print(f"capm-field spot-bridge: error: {bad}", file=sys.stderr)
        return 2
    try:
        import bosdyn.client  # noqa: F401
    except ImportError:
        print("capm-field spot-bridge: error: bosdyn-client is not installed (pip install 'capm-field[spot]')",
              file=sys.stderr)
        return 2
    link = LinkConfig(listen=tuple(a.listen), connect=tuple(a.connect), lease_ms=a.lease_ms, config_file=a.zenoh_config)
    try:  # before touching the robot: a missing certificate or an unsecured endpoint stops here
        check_link_security(link_security(link.zenoh_config()), a.insecure)
    except Exception as e:  # noqa: BLE001 - OSError, ValueError, zenoh's ZError (endpoints, config)
        print(f"capm-field spot-bridge: error: {zenoh_error_text(e)[:400]}", file=sys.stderr)
        return 2
    cfg = BodyConfig(max_speed=a.max_speed, max_yaw_rate=a.max_yaw_rate)
    try:
        backend, cleanup = connect_spot(a.hostname, cfg, a.field_in_odom, a.spot_estop_timeout)
    except SpotUnavailable as e:
        print(f"capm-field spot-bridge: error: {e}", file=sys.stderr)
        return e.exit_code
    server = None
    try:
        server = BodyServer(backend, ServerConfig(robot_id=a.robot_id, link=link, estop_timeout_s=a.estop_timeout,
                                                  lease_ttl_s=a.lease_ttl, allow_insecure=a.insecure)).start()
        print(f"spot-bridge: serving capm/{a.robot_id}/body on {', '.join(a.listen)}", flush=True)
        done = threading.Event()
        signal.signal(signal.SIGTERM, lambda *_: done.set())  # systemd stop: clean power-off path
        while not done.wait(1.0):
            pass
        return 0
    finally:
        if server is not None:
            server.close()
        cleanup()
