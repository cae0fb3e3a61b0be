"""Malformed files on every command that reads one: mission files, prescan files, the zenoh config,
fault schedules, run logs for `review`, and the spot-bridge's options. Each must end in one clear
error (exit 2, naming the field / line), never a Python traceback, and nothing written.

In-process (`capm_field.cli.main`) so that an uncaught exception fails the test itself and the
whole file runs in seconds; the CLI's own subprocess behaviour is pinned in test_mission_config.py.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from capm_field import cli
from capm_field.config import ArmConfig, BodyConfig, CameraConfig, TaskConfig
from mission.config import MissionError, load_mission
from test_mission_config import GOOD  # the minimal good mission the cases below spoil

HW = "field: {trois: [{x: 1, y: 1, r: 0.2}]}\nstart: {x: 0, y: 0}\ndrivers:\n  kind: hardware\n  zenoh: ZENOH\n"


def _validate(tmp_path: Path, text: str | bytes, capsys, name: str = "m.yaml") -> tuple[int, str]:
    p = tmp_path / name
    p.write_bytes(text.encode() if isinstance(text, str) else text)
    rc = cli.main(["validate", str(p)])
    return rc, capsys.readouterr().err


# ---- mission files: each was accepted by `validate` (or crashed it) before ------------------------
@pytest.mark.parametrize(
    "text, expect",
    [
        # YAML keys that are not scalars (a `? [a, b]` key) crashed the line map (TypeError: unhashable)
        (GOOD + "? [a, b]\n: 1\n", "unhashable key"),
        (GOOD + "? {a: 1}\n: 1\n", "unhashable key"),
        # timeouts: a typo, zero, negative, huge (an OverflowError mid-run), yes/no
        (GOOD + "timeouts: {bdy: 30}\n", ":6: timeouts.bdy: Input should be 'body', 'arm' or 'camera'"),
        (GOOD + "timeouts: {arm: -5}\n", ":6: timeouts.arm: Input should be greater than 0"),
        (GOOD + "timeouts: {camera: 0}\n", ":6: timeouts.camera: Input should be greater than 0"),
        (GOOD + "timeouts: {body: 1e300}\n", ":6: timeouts.body: Input should be less than or equal to 3600"),
        (GOOD + "timeouts: {body: yes}\n", ":6: timeouts.body: a number is needed, not a yes/no value"),
        # yes/no where a number is needed, nested anywhere
        (GOOD.replace("seed: 3", "seed: true"), ":5: drivers.seed: a number is needed, not a yes/no value"),
        (GOOD + "robot: {body: {operating_height: yes}}\n", ":6: robot.body.operating_height: a number is needed"),
        (GOOD + "robot: {body: {arm_mount: {xyz: [on, 0, 0]}}}\n", "robot.body.arm_mount.xyz: a number is needed"),
        # robot / task values that crashed the run's planning core (singular matrix, empty arrays)
        (GOOD + "robot: {body: {operating_height: 1e9}}\n", "robot.body.operating_height: Input should be less than or equal to 2"),
        (GOOD + "robot: {camera: {width: 100000000000}}\n", "robot.camera.width: Input should be less than or equal to 8192"),
        (GOOD + "robot: {nozzle: {tool: {xyz: [100, 0, 0]}}}\n", "robot.nozzle.tool.xyz.0: Input should be less than or equal to 2"),
        (GOOD + "robot: {arm: {stow_joints: [0, 1]}}\n", "robot.arm.stow_joints: the Z1 has 6 joints: give 6 values (got 2)"),
        (GOOD + "robot: {arm: {stow_joints: [3, 0, 0, 0, 0, 0]}}\n", "robot.arm.stow_joints: joint(s) [1] outside the limits"),
        (GOOD + "robot: {arm: {urdf: /nonexistent/z1.urdf}}\n", "robot.arm.urdf: URDF file not found"),
        (GOOD + "task: {gamma: 1e308}\n", "task.gamma: Input should be less than or equal to 1000"),
        (GOOD + "task: {eps_max: 1e300}\n", "task.eps_max: Input should be less than or equal to 4"),
        # TROI ids end up in log entity paths and summary keys
        ("field:\n  trois:\n    - {id: \"a/b\\n\", x: 1, y: 1, r: 0.2}\nstart: {x: 0, y: 0}\ndrivers: {kind: bench}\n",
         ":3: field.trois.0.id: a TROI id is 1-64 printable characters"),
        # output.dir '' wrote into the current directory; a NUL crashed mkdir
        (GOOD + "output: {dir: ''}\n", ":6: output.dir: needs a directory name"),
        (GOOD + "output: {dir: \"a\\0b\"}\n", ":6: output.dir: needs a directory name"),
        # fault schedules: parameters were read only when the fault fired (a NaN slip was injected)
        (GOOD.replace("seed: 3", "seed: 3, faults: [{kind: slip, target: 0, params: {dx: .nan}}]"),
         "fault slip: parameter dx must be a number in [-5, 5] (got nan)"),
        (GOOD.replace("seed: 3", "seed: 3, faults: [{kind: slip, target: 0, params: {dx: abc}}]"), "parameter dx must be a number"),
        (GOOD.replace("seed: 3", "seed: 3, faults: [{kind: slip, target: 0, params: {zzz: 1}}]"), "unknown parameter 'zzz'"),
        (GOOD.replace("seed: 3", "seed: 3, faults: [{kind: black_frame, target: 0, params: {frames: 2.5}}]"),
         "fault black_frame: parameter frames must be a whole number in [1, 1000] (got 2.5)"),
        (GOOD.replace("seed: 3", "seed: 3, faults: [{kind: camera_drop, target: 0, params: {frames: 0}}]"),
         "parameter frames must be a whole number"),
        (GOOD.replace("seed: 3", "seed: 3, faults: 'random:1" + "0" * 5000 + "'"), "random seed must be ≤"),
        # hardware links: checked here, not when zenoh or python-can refuse them at run time
        (HW.replace("ZENOH", "{connect: [garbage]}"), "drivers.zenoh.connect: a zenoh endpoint is <protocol>/<address>"),
        (HW.replace("ZENOH", "{robot_id: 'a/b*'}"), "drivers.zenoh.robot_id: robot_id must match"),
        (HW.replace("ZENOH", "{lease_s: 1e300}"), "drivers.zenoh.lease_s: Input should be less than or equal to 60"),
        (HW.replace("ZENOH", "{}") + "  can: {interface: nope}\n", "drivers.can.interface: unknown python-can interface 'nope'"),
    ],
    ids=lambda v: v if isinstance(v, str) and len(v) < 40 else None,
)
def test_bad_mission_is_one_clear_error(tmp_path, capsys, text, expect):
    rc, err = _validate(tmp_path, text, capsys)
    assert rc == 2 and expect in err, err
    assert err.startswith("capm-field validate: error:") and "Traceback" not in err


@pytest.mark.parametrize(
    "content, expect",
    [
        (b"", "must be a mapping"), (b"- 1\n- 2\n", "must be a mapping"), (b"42\n", "must be a mapping"),
        (b"{{{ ::: [[[\n", "YAML syntax error"), (b"field: \xff\xfe\n", "cannot read"), (bytes(range(256)), "cannot read"),
        (GOOD.encode() + b"bogus: 1\n", ":6: bogus: Extra inputs are not permitted"),
        (GOOD.replace("x: 1.0", "x: .nan").encode(), "field.trois.0.x: Input should be a finite number"),
        (GOOD.replace("x: 1.0", "x: 9000").encode(), "the walk from start to T00 is 9000.0 m"),
        (GOOD.encode() + b"start: {x: 1, y: 1}\n", "start: key given twice"),
    ],
)
def test_not_a_mission_is_one_clear_error(tmp_path, capsys, content, expect):
    rc, err = _validate(tmp_path, content, capsys)
    assert rc == 2 and expect in err and "Traceback" not in err, err


def test_prescan_files_bounded_and_checked(tmp_path, capsys):
    m = "field: {prescan: p.EXT}\nstart: {x: 0, y: 0}\ndrivers: {kind: bench}\n"
    cases = {
        # an integer of 5000 digits: json raised ValueError (not JSONDecodeError) → traceback
        "geojson": (b'{"features": [{"geometry": {"type": "Point", "coordinates": [1' + b"0" * 5000 + b', 1]}, '
                    b'"properties": {"radius": 0.2}}]}', "invalid JSON"),
        "csv": (b"x,y,r,id\n1,1,0.2,weed\t1/2\n", "a TROI id is 1-64 printable characters"),
    }
    for ext, (content, expect) in cases.items():
        (tmp_path / f"p.{ext}").write_bytes(content)
        rc, err = _validate(tmp_path, m.replace("EXT", ext), capsys)
        assert rc == 2 and expect in err and "Traceback" not in err, err
    # too many TROIs (validation ordered them for minutes) and too large a file: refused at once
    (tmp_path / "p.csv").write_text("x,y,r\n" + "1,1,0.2\n" * 5001)
    with pytest.raises(MissionError, match="5001 TROIs, more than one mission takes"):
        load_mission(_write(tmp_path, m.replace("EXT", "csv")))
    with open(tmp_path / "p.csv", "wb") as f:
        f.truncate(17 * 2**20)
    with pytest.raises(MissionError, match="too large for a prescan file"):
        load_mission(_write(tmp_path, m.replace("EXT", "csv")))


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "m.yaml"
    p.write_text(text)
    return p


def test_config_models_refuse_yes_no_and_implausible_values():
    """The pydantic configs themselves (also built from code and other files), not just missions."""
    for model, kw in ((BodyConfig, {"max_speed": True}), (ArmConfig, {"stow_joints": (0.0,) * 7}),
                      (CameraConfig, {"fx": 1e9}), (TaskConfig, {"sigma_scale": 1e9}), (BodyConfig, {"max_speed": float("nan")})):
        with pytest.raises(ValueError):
            model(**kw)
    assert BodyConfig(max_speed=1.6).max_speed == 1.6 and ArmConfig().stow_joints[2] == -0.005


def test_angles_in_degrees_and_a_tilted_arm_mount_are_refused(tmp_path, capsys):
    """A hand-eye rpy of (-90, 0, -90) (degrees) built a meaningless camera and the maps went on
    with it; a pitched arm mount was planned with a level base's maps (15 of 120 targets answered
    wrongly at 0.25 rad, an audit). Both are now mission errors naming the key."""
    text = GOOD + "robot:\n  body: {arm_mount: {rpy: [0, 0.25, 0]}}\n  camera: {hand_eye: {rpy: [-90, 0, -90]}}\n"
    rc, err = _validate(tmp_path, text, capsys)
    assert rc == 2 and ":7: robot.body.arm_mount: roll and pitch must be 0" in err, err
    assert ":8: robot.camera.hand_eye.rpy.0: Input should be greater than or equal to -6.2832 (got -90)" in err, err
    # a yawed mount and radians are fine
    assert BodyConfig(arm_mount={"xyz": (0.1, 0.0, 0.0), "rpy": (0.0, 0.0, 1.0)}).arm_mount.rpy[2] == 1.0
    assert CameraConfig(hand_eye={"rpy": (-1.5708, 0.0, -1.5708)}).hand_eye.rpy[0] == -1.5708


def test_a_focal_length_under_a_pixel_is_refused(tmp_path, capsys):
    """fx = 1e-20 px passed every bound: the maps came out NaN and `run` flew the mission on them
    (0 of 1 flamed, exit 0; with fy too, `internal error: AssertionError`, exit 1) instead of
    refusing the file. A focal length under 1 px is a unit error (metres: a 4 mm lens is 0.004)."""
    for kw in ({"fx": 1e-20}, {"fy": 0.004}):
        with pytest.raises(ValueError):
            CameraConfig(**kw)
    rc, err = _validate(tmp_path, GOOD + "robot: {camera: {fx: 1.0e-20}}\n", capsys)
    assert rc == 2 and ":6: robot.camera.fx: Input should be greater than or equal to 1" in err, err
    assert CameraConfig(fx=1.0, fy=1.0).fx == 1.0


def test_run_with_an_unplannable_robot_is_exit_2_and_writes_nothing(tmp_path, capsys):
    """Values inside every bound whose geometry still fails (here: a flame that may not tilt at
    all) crashed the planning core with a traceback, then were one line naming numpy's "zero-size
    array"; now the line says R_m is empty and why, exit 2, no output. `validate` builds the
    same maps and says the same (it said "ok", and only `run` refused)."""
    p = _write(tmp_path, GOOD + "robot: {nozzle: {max_tilt: 1.0e-9}}\n")
    out = tmp_path / "out"
    assert cli.main(["run", str(p), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "R_m is empty: no arm pose points the nozzle within robot.nozzle.max_tilt" in err, err
    assert "nothing was started" in err and "zero-size" not in err
    assert not out.exists()
    assert cli.main(["validate", str(p)]) == 2
    err = capsys.readouterr().err
    assert "R_m is empty: no arm pose points the nozzle within robot.nozzle.max_tilt" in err and "ok" not in err, err


# ---- zenoh config files ---------------------------------------------------------------------------
def test_zenoh_config_nested_too_deep_is_refused_not_a_segfault(tmp_path, capsys):
    """zenoh's JSON5 parser recurses: ~20 000 nested brackets killed the process (SIGSEGV)."""
    from drivers.body_protocol import load_config_file

    (tmp_path / "z.json5").write_text('{"a":' * 30000 + "1" + "}" * 30000)
    with pytest.raises(ValueError, match="brackets nested 30000 deep"):
        load_config_file(tmp_path / "z.json5")
    rc, err = _validate(tmp_path, HW.replace("ZENOH", "{config_file: z.json5}"), capsys)
    assert rc == 2 and "drivers.zenoh.config_file z.json5" in err and "nested" in err, err


def test_zenoh_config_with_pem_armour_around_garbage_is_refused(tmp_path, capsys):
    (tmp_path / "ca.pem").write_text("-----BEGIN CERTIFICATE-----\nAAAA\n-----END CERTIFICATE-----\n")
    (tmp_path / "z.json5").write_text('{transport: {link: {tls: {root_ca_certificate: "ca.pem"}}}}')
    rc, err = _validate(tmp_path, HW.replace("ZENOH", "{config_file: z.json5}"), capsys)
    assert rc == 2 and "holds no valid certificate" in err, err


# ---- run logs for review ----------------------------------------------------------------------------
def _mcap(path: Path, channels: list[tuple[str, str, str, str, bytes, list[bytes]]]) -> Path:
    from mcap.writer import Writer

    with path.open("wb") as f:
        w = Writer(f)
        w.start()
        for topic, enc, sname, senc, sdata, payloads in channels:
            sid = w.register_schema(sname, senc, sdata) if sname else 0
            cid = w.register_channel(topic, enc, sid)
            for i, pl in enumerate(payloads):
                w.add_message(cid, 1_700_000_000_000_000_000 + i * 10**6, pl, 0)
        w.finish()
    return path


def test_review_skips_foreign_and_undecodable_messages(tmp_path, capsys):
    """A file whose channels carry other encodings or corrupt payloads on our topics crashed the
    review (DecodeError, AttributeError on bytes); they are skipped, counted and named."""
    from mission.runlog_read import iter_run

    from mission.runlog_read import ReadReport
    from mission.runlog_schema import descriptor_set_bytes, message_class

    energy = message_class("Energy")(total=2.5).SerializeToString()
    foreign = [
        # our schema, one corrupt payload among good ones: that one is skipped
        ("/energy", "protobuf", "capm.log.Energy", "protobuf", descriptor_set_bytes(), [energy, b"\xff\xff\xff garbage", energy]),
        ("/tf", "json", "foxglove.FrameTransforms", "jsonschema", b"{}", [b'{"transforms": []}']),
        ("/energy", "json", "x", "jsonschema", b"{}", [b'{"total": 1}']),
        ("/other", "json", "x", "jsonschema", b"{}", [b"{}"]),
    ]
    p = _mcap(tmp_path / "foreign.mcap", foreign)
    assert cli.main(["review", str(p), "--rrd", str(tmp_path / "o.rrd")]) == 0
    err = capsys.readouterr().err
    assert "Traceback" not in err and "3 message(s) skipped, not readable as this run log's" in err, err
    assert "(first: /energy: DecodeError" in err
    # a schema that is no descriptor set: our reader skips it, and leaves it out of the copy handed to
    # Rerun's importer (which refused the whole file for it)
    p = _mcap(tmp_path / "bad.mcap", foreign + [("/plan", "protobuf", "capm.log.Plan", "protobuf", b"not a descriptor set", [b"\x00"])])
    rep = ReadReport()
    assert [m.topic for m in iter_run(p, report=rep)] == ["/energy", "/energy", "/tf", "/energy", "/other"]
    assert rep.undecodable == 2 and rep.undecodable_note.startswith("/energy: DecodeError")
    assert cli.main(["review", str(p), "--rrd", str(tmp_path / "o.rrd")]) == 0
    cap = capsys.readouterr()
    assert "4 message(s) skipped" in cap.err and "Traceback" not in cap.err and "(3 messages; 4 skipped" in cap.out, cap


@pytest.mark.parametrize("args, expect", [
    (["--web-port", "99999"], "argument --web-port:"), (["--grpc-port", "0"], "argument --grpc-port:"),
    (["--web-port", "x"], "argument --web-port:"), (["--web-port", "9911", "--grpc-port", "9911"], "must differ"),
])
def test_review_refuses_ports_no_viewer_can_take(cli_run, tmp_path, args, expect):
    """--web-port 99999 (or one port for both) printed a viewer address, then the viewer failed
    with its own usage text or a port already used."""
    r = cli_run(["review", str(tmp_path), "--web", *args])
    assert r.returncode == 2 and expect in r.stderr and "web viewer" not in r.stdout, r


def test_review_to_a_directory_is_one_line(tmp_path, capsys):
    p = _mcap(tmp_path / "r.mcap", [("/other", "json", "x", "jsonschema", b"{}", [b"{}"])])
    assert cli.main(["review", str(p), "--rrd", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "--rrd" in err and "is a directory" in err and "Traceback" not in err


# ---- spot-bridge options ------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "extra, expect",
    [
        (["--estop-timeout", "nan"], "--estop-timeout must be in [0.1, 60]"),
        (["--estop-timeout", "1e-300"], "--estop-timeout must be in [0.1, 60]"),
        (["--lease-ttl", "1e-300"], "--lease-ttl must be in [0.1, 600]"),
        (["--field-in-odom", "1e308,0,0"], "x and y within ±10000 m"),
        (["--hostname", ""], "--hostname: empty"),
        (["--lease-ms", "-5"], "--lease-ms must be in"),
        (["--robot-id", "a/b"], "--robot-id: robot_id must match"),
        (["--max-speed", "1e9"], "--max-speed: Input should be less than or equal to 5"),
        (["--listen", "garbage"], "Endpoints must be of the form"),  # zenoh's own error, without its Rust file
    ],
)
def test_spot_bridge_refuses_bad_options_before_touching_the_robot(monkeypatch, capsys, extra, expect):
    from drivers import spot_bridge

    def never(*_a, **_k):
        raise AssertionError("connect_spot reached")

    monkeypatch.setattr(spot_bridge, "connect_spot", never)
    args = ["--hostname", "spot", "--listen", "tcp/127.0.0.1:7447"] + extra
    try:
        rc = spot_bridge.main(args)
    except SystemExit as e:  # argparse's own refusals
        rc = e.code
    assert rc == 2
    err = capsys.readouterr().err
    assert expect in err and ".rs:" not in err and "Json5Err" not in err and "Message {" not in err, err


@pytest.mark.parametrize(
    "text, expect",
    [
        ('{ mode: "peer", transport: { link: { tx: { lease: "abc" } } } }', "line 1, column 51: error parsing number"),
        ('{ mode: "peer",\n  bogus_key: 3 }', "line 2, column 3: unknown field `bogus_key`, expected one of"),
        ('{ transport: { link: { tls: { root_ca_certificate: 5 } } } }', "invalid type: integer `5`, expected a string"),
        ('{ mode: "peer" ', "line 1, column 9: expected"),
    ],
)
def test_zenoh_config_errors_read_as_one_line_without_rust_debug_text(tmp_path, text, expect):
    """zenoh's own parse errors (a real zenoh.Config.from_file) read out of serde's and the JSON5
    parser's debug structs: `Message { msg: "...", location: Some(Location { line: .. }) } at
    /root/.cargo/...rs:1484.`"""
    from drivers.body_protocol import load_config_file, zenoh_error_text

    f = tmp_path / "z.json5"
    f.write_text(text)
    with pytest.raises(Exception) as e:
        load_config_file(f)
    line = zenoh_error_text(e.value)
    assert expect in line and "\n" not in line, line
    assert not any(junk in line for junk in ("Message {", "Location", ".rs:", "-->")), line


def test_spot_bridge_without_credentials_and_no_terminal_is_one_line(monkeypatch, capsys):
    """The SDK prompted for a password and died with a traceback under systemd."""
    from drivers import spot_bridge

    monkeypatch.delenv("BOSDYN_CLIENT_USERNAME", raising=False)
    monkeypatch.setattr(spot_bridge.sys.stdin, "isatty", lambda: False, raising=False)
    with pytest.raises(spot_bridge.SpotUnavailable, match="BOSDYN_CLIENT_USERNAME") as ei:
        spot_bridge.connect_spot("spot", BodyConfig(), None, 9.0)
    assert ei.value.exit_code == 2


# ---- a software fault mid-run ---------------------------------------------------------------------
def test_a_software_fault_mid_hold_ends_safe_and_recorded(core, tmp_path):
    """Values the schema cannot rule out may still break a planner mid-mission (an AssertionError
    from a degenerate camera, seen with fx = 1e5): the exception escaped `Executive.run` — no
    summary, exit 1 with a traceback. Now: flame off, mission aborted, traceback in the run log."""
    import time as _time

    from capm_field.camera import PinholeCamera
    from capm_field.geometry import SE2
    from capm_field.keystates import TROI
    from capm_field.planners import make_planner
    from mission.executive import Executive
    from mission.runlog import RunLog
    from mission.runlog_read import iter_run
    from sim_bench.bench_drivers import open_bench_drivers

    trois = [TROI(1.0, 0.3, 0.22, "A")]
    d = open_bench_drivers(core.robot, core.task, trois, SE2(0.0, 0.0, 0.0), 2)
    clock, wall0 = d.extras["world"].clock, _time.time_ns()
    lit: list[bool] = []

    def hook(target: int, phase: str, elapsed_s: float = 0.0) -> set[str]:
        if phase == "flame" and elapsed_s > 0.5:
            lit.append(d.igniter.board.flame_on)
            raise RuntimeError("boom in the middle of a hold")
        return set()

    log = RunLog(tmp_path / "run.mcap", core.robot, PinholeCamera.from_config(core.robot.cfg.camera), bench=True)
    ex = Executive(trois, SE2(0.0, 0.0, 0.0), SE2(2.0, 0.0, 0.0), d, core, make_planner("c", core), log=log,
                   truth=d.extras["world"].truth, now_ns=lambda: wall0 + clock.now_ns(), hook=hook)
    try:
        result = ex.run()
        flame_after, armed_after = d.igniter.board.flame_on, d.igniter.board.armed
    finally:
        d.close()
        log.close()
    assert lit == [True]  # the fault struck with the flame on
    assert result.aborted == "internal error: RuntimeError: boom in the middle of a hold"
    assert not flame_after and not armed_after
    assert result.targets[0].reason == "mission_aborted" and not result.targets[0].flamed
    logs = [m.data.message for m in iter_run(tmp_path / "run.mcap", topics={"/log"})]
    assert any("Traceback" in t and "boom in the middle of a hold" in t for t in logs)
