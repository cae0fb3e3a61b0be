"""The body contract, run against the in-process SimBodyDriver and the real ZenohBody over a
wire-level sim (loopback zenoh, server in a thread). Same tests, same expectations: the
mission executive cannot tell them apart."""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass
from typing import Callable

import pytest

from capm_field.config import BodyConfig
from capm_field.geometry import SE2
from drivers.interfaces import Body, BodyState, DriverTimeout, EStopActive
from sim_bench.sim_body import SimBody, SimBodyDriver
from sim_bench.zenoh_body_server import free_port, serve_sim_body

# A brisk body keeps the real-time (wire) variant short; both variants use the same limits.
FAST = BodyConfig(max_speed=2.0, max_accel=4.0, max_yaw_rate=3.0)


@dataclass
class Harness:
    body: Body
    sim: SimBody
    settle: Callable[[], None]  # let the state reach the driver (a no-op in process)
    later: Callable[[float, Callable[[], None]], None]  # call from elsewhere after a delay (sim or real s)


def _timer(delay: float, fn: Callable[[], None]) -> None:
    t = threading.Timer(delay, fn)
    t.daemon = True
    t.start()


@pytest.fixture(params=["inprocess", "zenoh"])
def harness(request):
    if request.param == "inprocess":
        drv = SimBodyDriver(SimBody(config=FAST, seed=3))
        yield Harness(drv, drv.sim, lambda: None, drv.sim.schedule)
        drv.close()
        return
    from drivers.zenoh_body import ZenohBody, ZenohBodyConfig

    port = free_port()
    bench = serve_sim_body("contract", [f"tcp/127.0.0.1:{port}"], body=FAST, seed=3)
    try:
        body = ZenohBody(ZenohBodyConfig.loopback(port, "contract"))
        try:
            yield Harness(body, bench.sim, lambda: time.sleep(0.05), _timer)
        finally:
            body.close()
    finally:
        bench.close()


def test_state_at_rest(harness):
    st = harness.body.state()
    assert isinstance(st, BodyState)
    assert st.powered and not st.estop and not st.moving and st.fault is None
    assert st.pose == SE2(0.0, 0.0, 0.0) and st.odometry_m == 0.0


def test_move_arrives_and_meters_distance(harness):
    goal = SE2(0.6, -0.3, 0.5)
    before = harness.body.state()
    r = harness.body.move_to(goal, timeout=10.0)
    assert r.ok and r.reason is None
    assert isinstance(r.final, SE2)
    assert r.final.distance(goal) < 0.03 and abs(r.final.yaw - goal.yaw) < 0.03
    harness.settle()
    st = harness.body.state()
    assert not st.moving
    assert st.pose.distance(r.final) < 1e-6
    assert st.odometry_m == pytest.approx(math.hypot(0.6, 0.3), abs=0.03)
    assert st.stamp_ns > before.stamp_ns
    assert r.extra["distance_m"] == pytest.approx(math.hypot(0.6, 0.3), abs=0.03)


def test_on_state_reports_the_path_and_a_failing_callback_does_not_stop_the_move(harness):
    """`on_state` gets the states of the walk in order (stamps rising, the pose advancing
    towards the goal); a callback that raises is ignored and the move still arrives."""
    goal = SE2(0.8, 0.0, 0.0)
    seen: list[BodyState] = []
    r = harness.body.move_to(goal, timeout=10.0, on_state=seen.append)
    assert r.ok, r
    assert len(seen) >= 5
    stamps = [s.stamp_ns for s in seen]
    assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)
    xs = [s.pose.x for s in seen]
    assert any(0.1 < x < 0.7 for x in xs)  # samples from the middle of the walk, not only its ends
    assert all(b >= a - 1e-3 for a, b in zip(xs, xs[1:]))

    calls = []

    def broken(st: BodyState) -> None:
        calls.append(st)
        raise RuntimeError("log full")

    r = harness.body.move_to(SE2(0.0, 0.0, 0.0), timeout=10.0, on_state=broken)
    assert r.ok and r.final.distance(SE2(0.0, 0.0, 0.0)) < 0.03
    assert len(calls) >= 2  # kept being called: one failure does not end the move


def test_timeout_stops_the_body(harness):
    with pytest.raises(DriverTimeout):
        harness.body.move_to(SE2(5.0, 0.0, 0.0), timeout=0.3)
    harness.settle()
    st = harness.body.state()
    assert not st.moving
    assert 0.0 < st.pose.x < 1.0


def test_motion_failure_is_a_failed_result(harness):
    harness.sim.inject_motion_failure(after_s=0.1, reason="blocked")
    r = harness.body.move_to(SE2(1.0, 0.0, 0.0), timeout=10.0)
    assert not r.ok and r.reason == "blocked"
    assert 0.0 < r.final.x < 1.0
    harness.settle()
    assert not harness.body.state().moving


def test_slip_arrives_with_an_offset(harness):
    harness.sim.inject_slip(0.2, 0.0)
    r = harness.body.move_to(SE2(0.3, 0.0, 0.0), timeout=10.0)
    assert r.ok
    assert r.final.x == pytest.approx(0.5, abs=0.03)


def test_estop_refuses_motion_until_released(harness):
    harness.sim.press_estop()
    harness.settle()
    assert harness.body.state().estop
    with pytest.raises(EStopActive):
        harness.body.move_to(SE2(0.3, 0.0, 0.0), timeout=5.0)
    harness.sim.release_estop()
    harness.settle()
    assert not harness.body.state().estop
    assert harness.body.move_to(SE2(0.3, 0.0, 0.0), timeout=10.0).ok


def test_estop_during_a_move_raises_and_stops(harness):
    harness.sim.schedule(0.2, harness.sim.press_estop)
    with pytest.raises(EStopActive):
        harness.body.move_to(SE2(2.0, 0.0, 0.0), timeout=10.0)
    harness.settle()
    st = harness.body.state()
    assert st.estop and not st.moving and 0.0 < st.pose.x < 1.0


def test_stop_from_another_thread_ends_the_move(harness):
    harness.later(0.2, harness.body.stop)  # as the executive would, from another thread
    r = harness.body.move_to(SE2(2.0, 0.0, 0.0), timeout=10.0)
    assert not r.ok and r.reason == "stop_requested"


def test_not_powered_is_a_failed_result(harness):
    harness.sim.set_power(False)
    harness.settle()
    assert not harness.body.state().powered
    r = harness.body.move_to(SE2(0.3, 0.0, 0.0), timeout=5.0)
    assert not r.ok and r.reason == "not_powered"


def test_stop_and_close_never_raise(harness):
    harness.body.stop()
    harness.body.stop()
    harness.body.close()
    harness.body.close()


def test_non_finite_goal_is_refused_before_anything_moves(harness):
    with pytest.raises(ValueError):
        harness.body.move_to(SE2(float("nan"), 0.0, 0.0), timeout=1.0)
    assert harness.sim.moves == 0
