"""Wire-level bench: the zenoh body protocol served for a `SimBody` on real time.

In a thread:   `with serve_sim_body(robot_id, listen=["tcp/127.0.0.1:PORT"]) as bench: ...`
As a process:  `python -m sim_bench.zenoh_body_server --listen tcp/127.0.0.1:PORT`
(prints one `READY <robot_id>` line when serving; SIGTERM/SIGINT close it cleanly), so tests
can SIGKILL or SIGSTOP the robot side. The bench listens on loopback only: any other listen
endpoint is refused. `config_file` / `--zenoh-config`: a zenoh JSON5 file with TLS, user/password
and the access-control list (mission/examples/zenoh-robot.json5, docs/security.md).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from dataclasses import dataclass

from capm_field.cli_args import seed as cli_seed
from capm_field.config import BodyConfig
from capm_field.geometry import SE2
from drivers.body_protocol import LinkConfig, is_loopback_endpoint
from drivers.body_server import BackendState, BodyBackend, BodyServer, ServerConfig
from sim_bench.sim_body import SimBody
from sim_bench.sim_clock import SimClock


class SimBackend(BodyBackend):
    """A real-time `SimBody` behind the server; `poll()` steps it to now."""

    def __init__(self, sim: SimBody) -> None:
        self.sim = sim

    def poll(self) -> BackendState:
        sim = self.sim
        sim.step_to(sim.clock.now_ns())
        snap = sim.snapshot()
        return BackendState(
            pose=snap.pose, moving=snap.moving, powered=snap.powered, estop=snap.estop,
            estop_reason=sim.estop_reason, odometry_m=snap.odometry_m, moves=sim.moves,
            fault=snap.fault, move=sim.status(),
        )

    def start_move(self, cmd_id: int, goal: SE2, timeout_s: float) -> None:
        self.sim.start_move(goal, cmd_id, timeout_s)

    def stop(self, reason: str) -> None:
        self.sim.stop(reason)

    def set_power(self, on: bool) -> None:
        self.sim.set_power(on)

    def keepalive(self, ok: bool, reason: str = "estop_keepalive_timeout") -> None:
        if ok:
            self.sim.release_estop("keepalive")
        else:
            self.sim.press_estop("keepalive", reason)

    def responsive(self) -> bool:
        return not self.sim.frozen


@dataclass
class SimBodyBench:
    """A running wire-level bench: the server, its sim (fault hooks) and its config."""

    server: BodyServer
    sim: SimBody

    def close(self) -> None:
        self.server.close()

    def __enter__(self) -> "SimBodyBench":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def serve_sim_body(
    robot_id: str = "spot",
    listen: list[str] | tuple[str, ...] = ("tcp/127.0.0.1:7447",),
    *,
    lease_ms: int = 1000,
    state_rate_hz: float = 100.0,
    estop_timeout_s: float = 1.0,
    lease_ttl_s: float = 2.0,
    seed: int = 0,
    body: BodyConfig | None = None,
    link: LinkConfig | None = None,
    config_file: str | None = None,
    pose: SE2 | None = None,
) -> SimBodyBench:
    """Start serving a real-time SimBody in this process (the server runs its own thread).
    Loopback endpoints only (ValueError otherwise): the bench is never reachable from outside."""
    link = link or LinkConfig(listen=tuple(listen), lease_ms=lease_ms, config_file=config_file)
    outside = [e for e in link.listen if not is_loopback_endpoint(e)]
    if outside or not link.listen:
        raise ValueError(f"the bench listens on loopback only (127.0.0.1 / ::1), got {list(link.listen)}")
    sim = SimBody(config=body, clock=SimClock(realtime=True), seed=seed, **({"pose": pose} if pose is not None else {}))
    cfg = ServerConfig(
        robot_id=robot_id,
        link=link,
        state_rate_hz=state_rate_hz,
        estop_timeout_s=estop_timeout_s,
        lease_ttl_s=lease_ttl_s,
    )
    return SimBodyBench(BodyServer(SimBackend(sim), cfg).start(), sim)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sim_bench.zenoh_body_server", description=__doc__.splitlines()[0])
    ap.add_argument("--listen", action="append", required=True, help="zenoh endpoint, e.g. tcp/127.0.0.1:7447 (repeatable)")
    ap.add_argument("--robot-id", default="spot")
    ap.add_argument("--lease-ms", type=int, default=1000, help="zenoh transport lease (ms)")
    ap.add_argument("--state-rate", type=float, default=100.0, help="state publication rate (Hz)")
    ap.add_argument("--estop-timeout", type=float, default=1.0, help="E-stop keep-alive timeout (s)")
    ap.add_argument("--lease-ttl", type=float, default=2.0, help="body lease TTL (s)")
    ap.add_argument("--seed", type=cli_seed, default=0)
    ap.add_argument("--zenoh-config", help="zenoh JSON5 config: TLS, user/password, access control (docs/security.md)")
    a = ap.parse_args(argv)
    done = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: done.set())
    bench = serve_sim_body(
        a.robot_id, a.listen, lease_ms=a.lease_ms, state_rate_hz=a.state_rate,
        estop_timeout_s=a.estop_timeout, lease_ttl_s=a.lease_ttl, seed=a.seed, config_file=a.zenoh_config,
    )
    try:
        print(f"READY {a.robot_id}", flush=True)
        while not done.wait(0.5):
            pass
    finally:
        bench.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())


# ---- helpers for tests and the bench -------------------------------------------------------------
def free_port() -> int:
    """A TCP port on loopback that was free a moment ago (bind to 0, read, release)."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def spawn_server(port: int, robot_id: str = "spot", *extra: str, timeout: float = 20.0, proto: str = "tcp"):
    """Start `python -m sim_bench.zenoh_body_server` on loopback; returns the Popen once READY.
    `proto="tls"` with `"--zenoh-config", FILE` in `extra` for the secured link."""
    import os
    import subprocess
    import time

    cmd = [sys.executable, "-m", "sim_bench.zenoh_body_server", "--listen", f"{proto}/127.0.0.1:{port}",
           "--robot-id", robot_id, *extra]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    deadline = time.monotonic() + timeout
    line = ""
    # readline blocks; a server that never gets ready dies on its own error (printed below)
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if line.startswith("READY") or not line:
            break
    if not line.startswith("READY"):
        proc.kill()
        err = proc.stderr.read()[-2000:]
        raise RuntimeError(f"body server on port {port} did not start: {err}")
    return proc
