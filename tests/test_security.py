"""Command-path security of the zenoh body link (docs/security.md): only authenticated peers
named in the robot side's access-control list can command the body, reach the E-stop keep-alive
or any igniter key; everybody else gets 0 commands through. The bench listens on loopback only.

Real zenoh sessions on loopback, the shipped templates (mission/examples/zenoh-*.json5) used
as they are, with a dev PKI made per test module in a temporary directory.
"""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh

from capm_field.config import BodyConfig
from capm_field.geometry import SE2
from drivers.body_protocol import Keys, LinkConfig, encode, link_security, load_config_file, pose_map
from drivers.body_server import BodyServer, InsecureLink, ServerConfig
from drivers.interfaces import LinkLost
from drivers.zenoh_body import ZenohBody, ZenohBodyConfig
from sim_bench.dev_pki import make_dev_pki
from sim_bench.sim_body import SimBody, SimClock
from sim_bench.zenoh_body_server import SimBackend, free_port, serve_sim_body, spawn_server
from waiting import wait_for

EXAMPLES = Path(__file__).resolve().parents[1] / "mission" / "examples"
RID = "spot"  # the robot id the templates' ACL is written for
FAST = BodyConfig(max_speed=2.0, max_accel=4.0, max_yaw_rate=3.0)
K = Keys(RID)
IGNITER_KEYS = (f"capm/{RID}/igniter/ignite", f"capm/{RID}/igniter/keepalive", f"capm/{RID}/igniter/extinguish")


@pytest.fixture(scope="module")
def pki(tmp_path_factory):
    """A directory laid out as the templates expect: certs/ + the two JSON5 files copied in."""
    d = tmp_path_factory.mktemp("pki")
    make_dev_pki(d / "certs", clients=("capm-commander", "capm-observer", "capm-intruder"))
    # A stranger's CA issuing a certificate with the right common name.
    make_dev_pki(d / "certs", clients=("capm-commander",), ca_name="stranger", ca_cn="capm-dev-ca")
    for name in ("zenoh-robot.json5", "zenoh-client.json5"):
        shutil.copy(EXAMPLES / name, d / name)
    (d / "users.txt").write_text("commander:correct-horse-battery\nviewer:viewer-pass\n")
    (d / "users.txt").chmod(0o600)
    return d


def tls_peer(pki: Path, port: int, cert: str | None, ca: str = "ca", mtls: bool = True) -> LinkConfig:
    """A hand-made peer on the robot's TLS port: trusts `ca`, presents certs/<cert>.pem (or none)."""
    o = {"transport/link/tls/root_ca_certificate": str(pki / "certs" / f"{ca}.pem")}
    if cert is not None:
        o |= {"transport/link/tls/connect_certificate": str(pki / "certs" / f"{cert}.pem"),
              "transport/link/tls/connect_private_key": str(pki / "certs" / f"{cert}.key")}
    if mtls:
        o["transport/link/tls/enable_mtls"] = True
    return LinkConfig(connect=(f"tls/127.0.0.1:{port}",), overrides=o)


class Probe:
    """Queryable + subscriber on the robot side's own session for the igniter keys: counts what
    arrives there (nothing may, from anybody: no rule allows those keys)."""

    def __init__(self, server: BodyServer) -> None:
        self.hits = 0
        self._lock = threading.Lock()
        s = server._session
        self._q = s.declare_queryable(f"capm/{RID}/igniter/**", self._on)
        self._s = s.declare_subscriber(f"capm/{RID}/igniter/**", self._on)

    def _on(self, x) -> None:
        with self._lock:
            self.hits += 1
        if isinstance(x, zenoh.Query):
            x.reply(x.key_expr, b"ignite")

    def close(self) -> None:
        self._q.undeclare()
        self._s.undeclare()


def attack(s: zenoh.Session, victim: str = "alice", wait: float = 0.6) -> dict[str, int]:
    """Every command-path action a peer can try, fired at once; returns the replies it got back.
    Queries: lease, move (forged lease), stop, power off, E-stop check-in (release and engage),
    lease release, wildcard queries over the body and the robot, igniter keys. Puts on command,
    E-stop and igniter keys. A forged liveliness token for the lease holder, then its deletion
    (that would make the robot drop the holder's lease and stop the body)."""
    got = {"ok": 0, "err": 0}
    lock = threading.Lock()

    def on_reply(r) -> None:
        with lock:
            got["ok" if r.ok is not None else "err"] += 1

    stop = encode("stop", {"client": "mallory"})
    queries = [
        (K.lease_acquire, encode("lease_acquire", {"client": "mallory"})),
        (K.cmd_move, encode("move", {"client": "mallory", "lease": "forged", "goal": pose_map(1, 0, 0), "timeout_ns": 10**9})),
        (K.cmd_stop, stop),
        (K.cmd_power, encode("power", {"client": "mallory", "lease": "forged", "on": False})),
        (K.estop_checkin, encode("checkin", {"client": "mallory", "seq": 1})),
        (K.estop_checkin, encode("checkin", {"client": "mallory", "seq": 2, "engage": True})),
        (K.lease_release, encode("lease_release", {"client": victim, "lease": "forged"})),
        (f"{K.prefix}/cmd/*", stop), (f"{K.prefix}/**", stop), (f"capm/{RID}/**", stop), ("capm/**", stop), ("**", stop),
        *((k, b"\x01") for k in IGNITER_KEYS), (f"capm/{RID}/igniter/**", b"\x01"),
    ]
    for key, payload in queries:
        s.get(key, on_reply, payload=payload, timeout=wait)
    for key in (K.cmd_move, K.cmd_stop, K.estop_checkin, K.state, *IGNITER_KEYS):
        s.put(key, stop)
    tok = s.liveliness().declare_token(K.client(victim))
    time.sleep(0.1)
    tok.undeclare()
    time.sleep(wait + 0.2)
    with lock:
        return dict(got)


COMMAND_STATS = ("q_move", "q_stop", "q_power", "q_lease_acquire", "q_lease_release", "q_checkin", "malformed",
                 "bad_version", "foreign_key", "foreign_put", "no_lease", "lease_refused", "estop", "commander_lost")


def commands_seen(stats: dict) -> int:
    return sum(stats.get(k, 0) for k in COMMAND_STATS)


def attack_all(sessions, **kw) -> dict[str, dict[str, int]]:
    """`attack` from every session at once (threads), by name; a session that zenoh refused to open
    (None) counts as refused."""
    from concurrent.futures import ThreadPoolExecutor

    live = {n: s for n, s in sessions.items() if s is not None}
    with ThreadPoolExecutor(max(1, len(live))) as ex:
        futs = {n: ex.submit(attack, s, **kw) for n, s in live.items()}
        return {n: (futs[n].result() if n in futs else {"ok": 0, "err": 0}) for n in sessions}


def open_peers(variants: dict[str, LinkConfig]) -> dict[str, zenoh.Session | None]:
    out: dict[str, zenoh.Session | None] = {}
    for name, link in variants.items():
        try:
            out[name] = zenoh.open(link.zenoh_config())
        except Exception:  # noqa: BLE001 - a config zenoh refuses outright is a refused attacker too
            out[name] = None
    return out


def test_mtls_acl_only_the_commander_commands(pki):
    port = free_port()
    with serve_sim_body(RID, [f"tls/127.0.0.1:{port}"], config_file=str(pki / "zenoh-robot.json5"), body=FAST) as bench:
        srv = bench.server
        assert srv.security["tls"] and srv.security["mtls"] and srv.security["acl"]
        probe = Probe(srv)
        variants = {
            "plain tcp to the TLS port": LinkConfig(connect=(f"tcp/127.0.0.1:{port}",)),
            "TLS, no client certificate": tls_peer(pki, port, None, mtls=False),
            "TLS, mTLS flag but no certificate": tls_peer(pki, port, None),
            "stranger CA, CN capm-commander": tls_peer(pki, port, "stranger-capm-commander"),
            "valid cert, CN not in ACL": tls_peer(pki, port, "capm-intruder"),
            "valid cert, the robot's own CN": tls_peer(pki, port, "robot"),
            "observer (read-only)": tls_peer(pki, port, "capm-observer"),
        }
        peers = open_peers(variants)
        try:
            # Only certificates from the robot's CA open a link at all; the ACL decides the rest.
            expected = {"capm-intruder", "capm-robot", "capm-observer"}
            assert wait_for(lambda: {a["auth"] for a in srv.peers.values()} >= expected, 5.0), srv.peers
            time.sleep(0.3)  # refused attempts had as long and more
            assert {a["auth"] for a in srv.peers.values()} == expected, srv.peers
            # Phase 1: no commander around. Every attack from every variant at once.
            results = attack_all(peers)
            accepted = sum(r["ok"] + r["err"] for r in results.values())
            print("\nmTLS+ACL attack results (replies per variant):", json.dumps(results))
            assert accepted == 0, results
            st = srv.stats
            assert commands_seen(st) == 0, st  # nothing reached the protocol code
            assert probe.hits == 0
            assert bench.sim.moves == 0 and not bench.sim.moving
            assert bench.sim.estop and bench.sim.estop_reason == "no_estop_checkin"  # no check-in got through
            assert srv.lease_holder is None
            # The observer reads state (read-only is allowed), nothing more.
            states: list[int] = []
            sub = peers["observer (read-only)"].declare_subscriber(K.state, lambda smp: states.append(1))
            assert wait_for(lambda: len(states) > 5, 2.0)
            sub.undeclare()

            # Phase 2: the commander (the client template as is) drives while the attacks go on.
            alice = ZenohBody(ZenohBodyConfig.loopback(port, RID, proto="tls", client_id="alice",
                                                       config_file=str(pki / "zenoh-client.json5")))
            try:
                assert srv.peers and "capm-commander" in {a["auth"] for a in srv.peers.values()}
                alice.acquire_lease()
                assert srv.lease_holder == "alice"
                out: dict = {}
                mover = threading.Thread(target=lambda: out.update(r=alice.move_to(SE2(1.5, 0.0, 0.0), 10.0)), daemon=True)
                mover.start()
                assert wait_for(lambda: bench.sim.moving, 2.0)
                during = attack_all(peers, wait=0.3)
                mover.join(10.0)
                assert out["r"].ok and out["r"].reason is None, out  # not stopped, not preempted
                assert sum(r["ok"] + r["err"] for r in during.values()) == 0
                st = srv.stats
                for k in ("q_stop", "q_power", "q_lease_release", "commander_lost", "no_lease", "lease_refused",
                          "foreign_key", "foreign_put", "malformed", "estop"):
                    assert st.get(k, 0) == 0, (k, st)
                assert st["q_move"] == 1 and srv.lease_holder == "alice" and not bench.sim.estop
                assert probe.hits == 0
                # The ACL is default deny for everybody: not even the commander reaches igniter keys.
                ign = [r for k in IGNITER_KEYS for r in alice._session.get(k, payload=b"\x01", timeout=0.3)]
                assert ign == [] and probe.hits == 0
            finally:
                alice.close()
            # Positive control: the same harness from a commander certificate does get through
            # (so the zeros above are the ACL's work, not a deaf harness).
            ctl = zenoh.open(tls_peer(pki, port, "capm-commander").zenoh_config())
            try:
                # its link is up (a fixed 0.2 s was little on a loaded machine), and a little more for routes
                assert wait_for(lambda: "capm-commander" in {a["auth"] for a in srv.peers.values()}, 5.0), srv.peers
                time.sleep(0.2)
                r = attack(ctl, victim="nobody")
                assert r["ok"] + r["err"] >= 7, r
                assert commands_seen(srv.stats) > 0 and probe.hits == 0
            finally:
                ctl.close()
        finally:
            for s in peers.values():
                if s is not None:
                    s.close()
            probe.close()


def test_usrpwd_acl_only_the_commander_commands(pki):
    """user/password (transport.auth.usrpwd) + ACL by username, over tcp on loopback."""
    port = free_port()
    acl_users = [{"id": "commanders", "usernames": ["commander"]}, {"id": "observers", "usernames": ["observer"]}]
    robot = LinkConfig(listen=(f"tcp/127.0.0.1:{port}",), config_file=str(pki / "zenoh-robot.json5"),
                       overrides={"transport/auth/usrpwd/dictionary_file": str(pki / "users.txt"),
                                  "access_control/subjects": acl_users})

    def user(name: str | None, pw: str | None) -> LinkConfig:
        o = {} if name is None else {"transport/auth/usrpwd/user": name, "transport/auth/usrpwd/password": pw}
        return LinkConfig(connect=(f"tcp/127.0.0.1:{port}",), overrides=o)

    with serve_sim_body(RID, link=robot, body=FAST) as bench:
        srv = bench.server
        assert srv.security["usrpwd"] and srv.security["acl"] and not srv.security["tls"]
        probe = Probe(srv)
        peers = open_peers({
            "no credentials": user(None, None),
            "wrong password": user("commander", "guess"),
            "unknown user": user("mallory", "correct-horse-battery"),
            "valid user not in ACL": user("viewer", "viewer-pass"),
        })
        try:
            assert wait_for(lambda: srv.stats.get("links_opened", 0) >= 1, 5.0)
            time.sleep(0.3)
            assert srv.stats.get("links_opened", 0) == 1  # only the valid (unlisted) user got a link
            results = attack_all(peers)
            print("\nusrpwd+ACL attack results (replies per variant):", json.dumps(results))
            assert sum(r["ok"] + r["err"] for r in results.values()) == 0, results
            assert commands_seen(srv.stats) == 0 and probe.hits == 0
            assert bench.sim.moves == 0 and bench.sim.estop and srv.lease_holder is None
            # The commander with the right password drives.
            cfg = ZenohBodyConfig(robot_id=RID, link=user("commander", "correct-horse-battery"), client_id="alice")
            alice = ZenohBody(cfg)
            try:
                assert alice.move_to(SE2(0.3, 0.0, 0.0), 5.0).ok
                assert srv.stats["q_move"] == 1 and srv.stats["q_checkin"] >= 1
            finally:
                alice.close()
        finally:
            for s in peers.values():
                if s is not None:
                    s.close()
            probe.close()


def _listening_addrs(port: int) -> set[str]:
    """Local addresses of LISTEN sockets on `port` (IPv4 and IPv6), from /proc/net/tcp*."""
    out = set()
    for f, width in (("/proc/net/tcp", 8), ("/proc/net/tcp6", 32)):
        try:
            lines = Path(f).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            cols = line.split()
            addr, p = cols[1].split(":")
            if int(p, 16) == port and cols[3] == "0A":  # 0A = LISTEN
                if width == 8:
                    out.add(".".join(str(int(addr[i:i + 2], 16)) for i in (6, 4, 2, 0)))
                else:
                    out.add("v6:" + addr)
    return out


def test_bench_listens_on_loopback_only(pki):
    port = free_port()
    with serve_sim_body(RID, [f"tcp/127.0.0.1:{port}"]):
        assert _listening_addrs(port) == {"127.0.0.1"}
    # Wire-level bench (subprocess) with the TLS config: loopback, and commandable only with a cert.
    port = free_port()
    proc = spawn_server(port, RID, "--zenoh-config", str(pki / "zenoh-robot.json5"), proto="tls")
    try:
        assert _listening_addrs(port) == {"127.0.0.1"}
        body = ZenohBody(ZenohBodyConfig.loopback(port, RID, proto="tls", config_file=str(pki / "zenoh-client.json5")))
        try:
            assert body.move_to(SE2(0.1, 0.0, 0.0), 10.0).ok
        finally:
            body.close()
        with pytest.raises(LinkLost, match="no robot side"):  # a client without certificates never gets in
            ZenohBody(ZenohBodyConfig(robot_id=RID, link=tls_peer(pki, port, None, mtls=False), connect_timeout_s=0.5))
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(5.0) == 0
    finally:
        proc.kill()
        proc.wait()
    # Anything but loopback is refused, before binding.
    for ep in ("tcp/0.0.0.0:7447", "tls/192.168.1.10:7447", "tcp/[::]:7447"):
        with pytest.raises(ValueError, match="loopback only"):
            serve_sim_body(RID, [ep])
    out = subprocess.run([sys.executable, "-m", "sim_bench.zenoh_body_server", "--listen", f"tcp/0.0.0.0:{free_port()}"],
                         capture_output=True, text=True, timeout=30)
    assert out.returncode != 0 and "loopback only" in out.stderr


def test_robot_side_refuses_to_serve_the_network_unsecured(pki):
    def server(link: LinkConfig, **kw) -> BodyServer:
        sim = SimBody(config=FAST, clock=SimClock(realtime=True))
        return BodyServer(SimBackend(sim), ServerConfig(robot_id=RID, link=link, **kw))

    # Checked before anything is bound: these never open a socket.
    for link in (
        LinkConfig(listen=("tcp/0.0.0.0:7447",)),  # nothing at all
        LinkConfig(listen=("tcp/127.0.0.1:7447",), connect=("tcp/10.0.0.1:7447",)),  # reachable through a router
        LinkConfig(listen=("tcp/127.0.0.1:7447",), multicast=True),  # scouting off the machine
        LinkConfig(listen=("tcp/192.168.50.5:7447",), config_file=str(pki / "zenoh-robot.json5")),  # TLS config on a tcp/ endpoint
        LinkConfig(listen=("tls/192.168.50.5:7447",), config_file=str(pki / "zenoh-robot.json5"),
                   overrides={"access_control/enabled": False}),  # no ACL
        LinkConfig(listen=("tls/192.168.50.5:7447",), config_file=str(pki / "zenoh-robot.json5"),
                   overrides={"transport/link/tls/enable_mtls": False}),  # no client authentication
    ):
        with pytest.raises(InsecureLink, match="refusing to serve"):
            server(link).start()
    sec = link_security(LinkConfig(listen=("tls/192.168.50.5:7447",), config_file=str(pki / "zenoh-robot.json5")).zenoh_config())
    assert sec["tls"] and sec["mtls"] and sec["acl"] and not sec["loopback_only"]


def test_config_files_resolve_paths_and_fail_early(pki, tmp_path):
    cfg = load_config_file(pki / "zenoh-client.json5")
    ca = json.loads(cfg.get_json("transport/link/tls/root_ca_certificate"))
    assert Path(ca).is_absolute() and Path(ca) == (pki / "certs" / "ca.pem").resolve()
    # A template copied without its certificates: a clear error at start, naming the key.
    shutil.copy(EXAMPLES / "zenoh-client.json5", tmp_path / "c.json5")
    with pytest.raises(FileNotFoundError, match="root_ca_certificate"):
        load_config_file(tmp_path / "c.json5")
    # The mission file's drivers.zenoh → client config (config_file relative to the mission file).
    from mission.config import ZenohSpec

    spec = ZenohSpec(robot_id=RID, connect=["tls/192.168.80.3:7447"], config_file="zenoh-client.json5", lease_s=1.0)
    zc = ZenohBodyConfig.from_spec(spec, base_dir=pki)
    assert zc.link.config_file == str(pki / "zenoh-client.json5") and zc.link.connect == ("tls/192.168.80.3:7447",)
    sec = link_security(zc.link.zenoh_config())
    assert sec["tls"] and sec["mtls"]
    # The hardware template points at the client template.
    import yaml

    hw = yaml.safe_load((EXAMPLES / "hardware_template.yaml").read_text())["drivers"]["zenoh"]
    assert hw["config_file"] == "zenoh-client.json5" and all(e.startswith("tls/") for e in hw["connect"])


def test_hostile_certificate_files_are_refused_quickly(pki, tmp_path):
    """A CA file of 60 000 BEGIN lines and no END (1.7 MB): the lazy regex once retried from each
    BEGIN took ~15 min (found by a fuzzing sweep); a 5 MB file is over the size limit; a directory
    or device is named as such, not as missing."""
    import os

    cfg_text = (pki / "zenoh-client.json5").read_text()
    ca = "certs/ca.pem"
    assert ca in cfg_text
    shutil.copytree(pki / "certs", tmp_path / "certs")

    def load_with(ca_path: str):
        (tmp_path / "c.json5").write_text(cfg_text.replace(ca, ca_path))
        return load_config_file(tmp_path / "c.json5")

    (tmp_path / "begins.pem").write_bytes(b"-----BEGIN CERTIFICATE-----\n" * 60_000)
    with pytest.raises(ValueError, match="begins.pem is not a PEM certificate"):
        load_with(str(tmp_path / "begins.pem"))
    big = (pki / "certs" / "ca.pem").read_bytes()
    (tmp_path / "big.pem").write_bytes(big + b"#" * (5 << 20))
    with pytest.raises(ValueError, match="too large for a PEM file"):
        load_with(str(tmp_path / "big.pem"))
    with pytest.raises(ValueError, match="which is not a regular file"):
        load_with(str(tmp_path / "certs"))
    os.mkfifo(tmp_path / "fifo.pem")
    with pytest.raises(ValueError, match="which is not a regular file"):
        load_with(str(tmp_path / "fifo.pem"))
    assert load_with(str(tmp_path / "certs" / "ca.pem"))  # the real one still loads


def test_spot_bridge_refuses_an_unsecured_endpoint_before_touching_the_robot(pki, monkeypatch, capsys):
    pytest.importorskip("bosdyn.client")
    from drivers import spot_bridge

    class Reached(Exception):
        pass

    def fake_connect(*a, **k):
        raise Reached

    monkeypatch.setattr(spot_bridge, "connect_spot", fake_connect)
    assert spot_bridge.main(["--hostname", "spot", "--listen", "tcp/192.168.50.5:7447"]) == 2
    assert "refusing to serve tcp/192.168.50.5:7447" in capsys.readouterr().err
    with pytest.raises(Reached):  # secured: goes on to the robot
        spot_bridge.main(["--hostname", "spot", "--listen", "tls/192.168.50.5:7447", "--zenoh-config",
                          str(pki / "zenoh-robot.json5")])
    with pytest.raises(Reached):  # explicit opt-out
        spot_bridge.main(["--hostname", "spot", "--listen", "tcp/192.168.50.5:7447", "--insecure"])
    missing = pki.parent / "elsewhere.json5"
    shutil.copy(EXAMPLES / "zenoh-robot.json5", missing)
    assert spot_bridge.main(["--hostname", "spot", "--listen", "tls/192.168.50.5:7447", "--zenoh-config", str(missing)]) == 2
    assert "names a missing file" in capsys.readouterr().err


def test_commander_does_not_talk_to_an_impostor_robot(pki):
    """A robot side with a certificate from another CA (same CN): the commander's TLS refuses it,
    so no check-in or command ever leaves for it (it could otherwise keep a real E-stop released
    nowhere, or learn the commander's traffic)."""
    port = free_port()
    fake = LinkConfig(listen=(f"tls/127.0.0.1:{port}",), config_file=str(pki / "zenoh-robot.json5"),
                      overrides={"transport/link/tls/listen_certificate": str(pki / "certs" / "stranger-robot.pem"),
                                 "transport/link/tls/listen_private_key": str(pki / "certs" / "stranger-robot.key"),
                                 "access_control/enabled": False})
    with serve_sim_body(RID, link=fake, body=FAST) as impostor:
        with pytest.raises(LinkLost, match="no robot side"):
            ZenohBody(ZenohBodyConfig.loopback(port, RID, proto="tls", connect_timeout_s=0.5,
                                               config_file=str(pki / "zenoh-client.json5")))
        assert commands_seen(impostor.server.stats) == 0 and impostor.server.stats.get("links_opened", 0) == 0
