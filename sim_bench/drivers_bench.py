"""`capm-field bench-drivers [--duration S] --json FILE`: transport figures on this machine.

zenoh body link: `sim_bench.zenoh_bench.measure_body_link` (imported lazily; optional).
CAN (python-can `virtual`, in-process, so these are software figures, not wire timing):
* arm joint-target streaming at 500 Hz for S s through the real `CanArm` to the simulated
  gateway: pairs sent, lost (sent - applied by the gateway), reordered (counter out of
  sequence at the gateway), achieved rate and the largest gap between applied targets;
* igniter cutoff: a host sends IGNITE keep-alives, then freezes; time from its last keep-alive
  to the flame-off status it receives (and to the board's own valve closing), over N trials;
* CAN heartbeat loss: time from the gateway's last heartbeat to `CanArm` declaring LinkLost.
CPU is shared: timing figures are noisy; each comes from many samples.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from capm_field.cli_args import count
from capm_field.errors import UserError, check_output, write_output
from drivers.can.codec import IGN_EXTINGUISH, IGN_IGNITE

from .can_rig import CanBench, RawHost


def _pct(xs: list[float], p: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, max(0, math.ceil(p / 100.0 * len(s)) - 1))]


# ---- CAN measurements (also used by tests) ---------------------------------------------------
def measure_can_stream(duration_s: float, bench: CanBench | None = None) -> dict:
    """Stream a smooth joint trajectory at 500 Hz for duration_s through CanArm -> gateway sim."""
    own = bench is None
    bench = bench or CanBench(with_igniter=False)
    try:
        arm, rs = bench.arm, bench.robot_side
        qc = np.array([0.0, 1.2, -1.2, 0.0, 0.5, 0.0])
        if not arm.move_joints(qc, timeout=10.0).ok:
            raise RuntimeError("could not reach the streaming start pose")
        amp = np.array([0.3, 0.2, 0.2, 0.3, 0.3, 0.3])  # peak speed 0.47 rad/s at 0.25 Hz

        def traj(t: float) -> np.ndarray:
            return qc + amp * math.sin(2 * math.pi * 0.25 * t)

        time.sleep(0.05)  # the move's last target pairs may still be queued at the gateway
        with rs.lock:
            applied0, inc0 = rs.stream.applied, rs.stream.incomplete
            rej0 = dict(rs.arm_rx.stats.rejected)
            lost0 = rs.arm_rx.stats.lost
            rs.stream.gaps_ns, rs.stream.record_gaps, rs.stream.max_gap_ns = [], True, 0
        failed = arm.stream(traj, duration_s, deadline=time.monotonic() + duration_s + 30.0)
        time.sleep(0.05)  # let the last pair land
        st = arm.last_stream
        with rs.lock:
            applied = rs.stream.applied - applied0
            rej = rs.arm_rx.stats.rejected
            reordered = sum(rej[k] - rej0.get(k, 0) for k in ("counter_sequence", "counter_repeated"))
            gaps = [g / 1e6 for g in rs.stream.gaps_ns]
            rs.stream.record_gaps = False
            counter_gaps = rs.arm_rx.stats.lost - lost0
            incomplete = rs.stream.incomplete - inc0
        return {
            "rate_hz": round(st.rate_hz, 2),
            "sent": st.sent,
            "lost": st.sent - applied,
            "reordered": reordered,
            "target_hz": arm.cfg.stream_rate_hz,
            "applied": applied,
            "incomplete_pairs": incomplete,
            "counter_gaps": counter_gaps,
            "overruns": st.overruns,
            "gap_ms_median": round(statistics.median(gaps), 3) if gaps else None,
            "gap_ms_p99": round(_pct(gaps, 99), 3) if gaps else None,
            "gap_ms_max": round(max(gaps), 3) if gaps else None,
            "fault": None if failed is None else failed.reason,
        }
    finally:
        if own:
            bench.close()


def measure_igniter_cutoff(trials: int = 10, hold_s: float = 0.1) -> dict:
    """Host freezes after its last keep-alive: how long until the flame is off?"""
    bench = CanBench(with_arm=False, with_igniter=False)
    host = RawHost(bench.bus)
    host_ms, board_ms = [], []
    try:
        ka = 1.0 / 50.0
        done = tries = 0
        while done < trials:
            tries += 1
            if tries > 3 * trials:  # the board tripped on most tries: this host cannot keep 50 Hz
                raise RuntimeError(f"igniter board tripped on {tries - 1 - done} of {tries - 1} tries (host stalls > 80 ms)")
            lit_at = host.light()  # ARM, IGNITE until lit (re-ARMs if a host stall tripped it)
            t_last = lit_at
            while t_last - lit_at < hold_s and host.ign_status["Armed"] == 1:
                time.sleep(ka)
                t_last = host.ign(IGN_IGNITE)
            if host.ign_status["Armed"] != 1:
                continue  # tripped during the hold (this host stalled > 80 ms): not a measurement
            # frozen host: no more keep-alives, no EXTINGUISH
            t_off = host.wait_ign(lambda s: s["FlameOn"] == 0 and s["Igniting"] == 0, 1.0)
            if t_off is None:
                raise RuntimeError("flame did not go off after the keep-alives stopped")
            board_s = bench.robot_side.board.flame_off_at - t_last
            host.ign(IGN_EXTINGUISH)
            time.sleep(0.02)
            if board_s < 0.5 * bench.robot_side.board.p.keepalive_timeout:
                continue  # off before the timeout could run out: a stall just before the last keep-alive tripped it
            done += 1
            host_ms.append((t_off - t_last) * 1e3)
            board_ms.append(board_s * 1e3)
    finally:
        host.close()
        bench.close()
    return {
        "trials": trials,
        "keepalive_timeout_ms": bench.robot_side.board.p.keepalive_timeout * 1e3,
        "host_seen_ms": {"median": round(statistics.median(host_ms), 2), "max": round(max(host_ms), 2)},
        "board_ms": {"median": round(statistics.median(board_ms), 2), "max": round(max(board_ms), 2)},
    }


def measure_can_link_loss(trials: int = 5, timeout_s: float = 0.3) -> dict:
    """Gateway heartbeat stops (node frozen): time from its last heartbeat to LinkLost in CanArm."""
    out = []
    bench = CanBench(with_igniter=False, heartbeat_timeout=timeout_s)
    try:
        rs, link = bench.robot_side, bench.arm.link
        for _ in range(trials):
            rs.faults.silent_heartbeat.add("HB_ARM_GW")
            t0 = time.monotonic()
            while link.ok and time.monotonic() - t0 < 3 * timeout_s + 1.0:
                time.sleep(0.002)
            if link.ok:
                raise RuntimeError("heartbeat loss not detected")
            out.append((link.lost_detected_ns - link.last_peer_hb_ns) / 1e6)
            rs.faults.silent_heartbeat.discard("HB_ARM_GW")
            t0 = time.monotonic()
            while not link.ok and time.monotonic() - t0 < 1.0:
                time.sleep(0.005)
    finally:
        bench.close()
    return {"timeout_ms": timeout_s * 1e3, "median": round(statistics.median(out), 2), "max": round(max(out), 2), "trials": trials}


# ---- CLI ---------------------------------------------------------------------------------------
class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # bad args are user errors: one line, exit 2 (cli.py)
        raise UserError(message)


MIN_DURATION_S = 0.5  # a few state periods and command round trips at least
MAX_DURATION_S = 86_400.0  # a day per transport; beyond it a typo (1e9 s ran as asked)


def _positive(s: str) -> float:
    try:
        v = float(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--duration must be a number of seconds, not {s!r}") from None
    if not (MIN_DURATION_S <= v <= MAX_DURATION_S):  # shorter: no round trip or state gap to measure (nan fails too)
        raise argparse.ArgumentTypeError(f"--duration must be in [{MIN_DURATION_S:g}, {MAX_DURATION_S:g}] s, not {s[:30]}")
    return v


def main(argv: list[str] | None = None) -> int:
    p = _Parser(prog="capm-field bench-drivers", description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=_positive, default=60.0, help="seconds of streaming per transport (default 60)")
    p.add_argument("--json", required=True, metavar="FILE", help="write the figures to FILE")
    p.add_argument("--cutoff-trials", type=count(1, 10_000), default=10, help="igniter cutoff trials (default 10)")
    a = p.parse_args(argv)
    out_path = Path(a.json)
    check_output(a.json, "--json")

    res: dict = {
        "zenoh_cmd_rtt_ms": None,
        "state_rate_hz": None,
        "state_max_gap_ms": None,
        "link_loss_detect_ms": None,
    }
    try:
        from sim_bench.zenoh_bench import measure_body_link  # written by the body (zenoh) work
    except ImportError as e:
        print(f"zenoh figures unavailable: {e}", file=sys.stderr)
    else:
        z = measure_body_link(a.duration)
        for k in ("zenoh_cmd_rtt_ms", "state_rate_hz", "state_max_gap_ms", "link_loss_detect_ms"):
            res[k] = z.get(k)

    print(f"CAN: streaming arm targets at 500 Hz for {a.duration:g} s ...", file=sys.stderr)
    res["can_stream"] = measure_can_stream(a.duration)
    cut = measure_igniter_cutoff(a.cutoff_trials)
    res["igniter_cutoff_ms"] = cut["host_seen_ms"]["max"]
    res["igniter_cutoff"] = cut
    res["can_link_loss_detect_ms"] = measure_can_link_loss()

    write_output(a.json, json.dumps(res, indent=2, allow_nan=False) + "\n", "--json")
    z = res["zenoh_cmd_rtt_ms"]
    if z:
        print(f"zenoh cmd rtt: median {z['median']} ms, p99 {z['p99']} ms")
        print(f"body state: {res['state_rate_hz']} Hz, max gap {res['state_max_gap_ms']} ms; link loss detected in {res['link_loss_detect_ms']} ms")
    else:
        print("zenoh figures: unavailable (sim_bench.zenoh_bench not present)")
    s = res["can_stream"]
    print(f"CAN arm stream: {s['rate_hz']} Hz, sent {s['sent']}, lost {s['lost']}, reordered {s['reordered']}, "
          f"gap median/p99/max {s['gap_ms_median']}/{s['gap_ms_p99']}/{s['gap_ms_max']} ms, overruns {s['overruns']}")
    print(f"igniter cutoff after last keep-alive: max {cut['host_seen_ms']['max']} ms (median {cut['host_seen_ms']['median']} ms, "
          f"board {cut['board_ms']['max']} ms max, {cut['trials']} trials, keep-alive timeout {cut['keepalive_timeout_ms']:g} ms)")
    ll = res["can_link_loss_detect_ms"]
    print(f"CAN heartbeat loss detected after {ll['median']} ms median, {ll['max']} ms max (timeout {ll['timeout_ms']:g} ms)")
    print(f"wrote {out_path}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
