"""Zenoh body link figures on loopback: the real `ZenohBody` against the sim server in another
process. `measure_body_link(60)` gives the figures quoted in docs/drivers.md; the
`capm-field bench-drivers` command calls it.
"""

from __future__ import annotations

import json
import os
import signal
import statistics
import sys
import threading
import time

from capm_field.geometry import SE2
from drivers.interfaces import BodyState, LinkLost
from drivers.zenoh_body import ZenohBody, ZenohBodyConfig
from sim_bench.zenoh_body_server import free_port, spawn_server

ROBOT_ID = "bench"


def _percentile(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, int(round(q / 100 * (len(s) - 1))))]


def _kill_detect_ms(sig: int, lease_ms: int) -> float:
    """Start a long move, send `sig` to the robot side, time until move_to raises LinkLost."""
    port = free_port()
    proc = spawn_server(port, ROBOT_ID, "--lease-ms", str(lease_ms))
    body = None
    try:
        body = ZenohBody(ZenohBodyConfig.loopback(port, ROBOT_ID, lease_ms=lease_ms))
        out: dict = {}

        def run() -> None:
            try:
                body.move_to(SE2(20.0, 0.0, 0.0), 60.0)
            except LinkLost:
                out["t"] = time.perf_counter()

        th = threading.Thread(target=run, daemon=True)
        th.start()
        end = time.monotonic() + 3.0
        while not body.state().moving and time.monotonic() < end:
            time.sleep(0.01)
        t0 = time.perf_counter()
        os.kill(proc.pid, sig)
        th.join(lease_ms / 1000 * 3 + 2)
        if "t" not in out:
            raise RuntimeError(f"link loss not reported after signal {sig}")
        return (out["t"] - t0) * 1e3
    finally:
        if body is not None:
            body.close()
        if sig == signal.SIGSTOP:
            os.kill(proc.pid, signal.SIGCONT)
        proc.kill()
        proc.wait()


def measure_body_link(duration_s: float, kill_trials: int = 3, lease_ms: int = 1000) -> dict:
    """Figures on loopback (noisy on a shared machine: many samples, medians and worst cases).

    zenoh_cmd_rtt_ms: command query → acknowledgement round trip (E-stop check-ins, ~200/s,
    for `duration_s`); state_rate_hz / state_max_gap_ms: the state stream as received by the
    adapter over the same period; link_loss_detect_ms: robot side SIGKILLed during a move →
    `LinkLost` raised by `move_to` (worst of `kill_trials`); frozen_detect_ms: SIGSTOP instead
    (bounded by the transport lease, here `lease_ms`).
    """
    port = free_port()
    proc = spawn_server(port, ROBOT_ID, "--lease-ms", str(lease_ms))
    try:
        body = ZenohBody(ZenohBodyConfig.loopback(port, ROBOT_ID, lease_ms=lease_ms))
        try:
            stamps: list[int] = []

            def on_state(st: BodyState) -> None:
                stamps.append(time.monotonic_ns())

            body.add_state_listener(on_state)
            rtts: list[float] = []
            end = time.monotonic() + duration_s
            while time.monotonic() < end:
                rtts.append(body.ping() * 1e3)
                time.sleep(0.005)
            lost = body.link_lost
        finally:
            body.close()
    finally:
        proc.terminate()
        proc.wait(5)
    gaps = [(b - a) / 1e6 for a, b in zip(stamps, stamps[1:])]
    kills = [_kill_detect_ms(signal.SIGKILL, lease_ms) for _ in range(kill_trials)]
    frozen = _kill_detect_ms(signal.SIGSTOP, lease_ms)
    return {
        "zenoh_cmd_rtt_ms": {"median": statistics.median(rtts), "p99": _percentile(rtts, 99), "n": len(rtts)},
        "state_rate_hz": (len(stamps) - 1) / ((stamps[-1] - stamps[0]) / 1e9) if len(stamps) > 1 else 0.0,
        "state_max_gap_ms": max(gaps) if gaps else None,  # (None, not inf: the figures are JSON)
        "link_loss_detect_ms": max(kills),
        "link_loss_detect_ms_trials": kills,
        "frozen_detect_ms": frozen,
        "transport_lease_ms": lease_ms,
        "duration_s": duration_s,
        "link_lost_during_run": lost,
    }


if __name__ == "__main__":
    print(json.dumps(measure_body_link(float(sys.argv[1]) if len(sys.argv) > 1 else 10.0), indent=2))
