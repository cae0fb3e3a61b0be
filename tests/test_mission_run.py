"""End to end on the bench: `capm-field run` → run.mcap (CRC-checked) + summary.json, and the
ignition interlock against the simulated drivers."""

import json
import subprocess
import sys

import pytest
from mcap.reader import make_reader

from capm_field.geometry import SE2
from capm_field.keystates import TROI
from mission.interlock import IgnitionInterlock

CLI = [sys.executable, "-m", "capm_field.cli"]

MISSION = """\
name: e2e
planner: {planner}
field:
  trois:
    - {{id: A, x: 1.0, y: 0.3, r: 0.22}}
    - {{id: B, x: 2.0, y: 0.8, r: 0.25}}
    - {{id: C, x: 1.2, y: 1.6, r: 0.24}}
start: {{x: 0.0, y: 0.0, yaw: 0.0}}
end: {{x: 2.5, y: 2.0}}
drivers: {{kind: bench, seed: {seed}}}
output: {{dir: {out}}}
"""


@pytest.fixture(scope="module")
def run_c(tmp_path_factory):
    d = tmp_path_factory.mktemp("run")
    m = d / "m.yaml"
    m.write_text(MISSION.format(planner="c", seed=5, out=d / "out"))
    r = subprocess.run(CLI + ["run", str(m), "--quiet"], capture_output=True, text=True, timeout=240)
    return r, d / "out"


def test_run_writes_summary_and_log(run_c):
    r, out = run_c
    assert r.returncode == 0, r.stderr
    s = json.loads((out / "summary.json").read_text())
    assert {t["id"] for t in s["targets"]} == {"A", "B", "C"}
    for t in s["targets"]:
        assert set(t) >= {"id", "troi", "mpoi_detected", "mpoi_true", "branch", "flamed", "epmc_true", "energy", "body_moves", "reason"}
        assert t["branch"] in ("upper", "lower", "skipped")
        if t["flamed"]:
            assert t["reason"] is None and t["body_moves"] >= 2 and t["energy"] > 0
        else:
            assert t["reason"]
    assert s["total_energy"] == pytest.approx(sum(t["energy"] for t in s["targets"]), rel=1e-9)
    assert 0 <= s["success_rate"] <= 1 and s["wall_s"] > 0


def test_run_log_is_valid_mcap_with_the_contract_topics(run_c):
    _, out = run_c
    topics = set()
    with open(out / "run.mcap", "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        for _schema, channel, _msg in reader.iter_messages():
            topics.add(channel.topic)
    assert {"/robot_description", "/camera/image", "/camera/calibration", "/log", "/key_state", "/plan", "/detection", "/regions", "/energy", "/igniter/state", "/truth/mpoi"} <= topics


def test_each_detection_logs_the_roi_it_searched_and_answers_inside_it(run_c):
    """/detection carries the ROI's rim on the raw image (review draws it): every detector answer
    of the run lies inside its ROI."""
    import cv2
    import numpy as np

    from mission.runlog_read import iter_run

    _, out = run_c
    dets = [m.data for m in iter_run(out / "run.mcap", topics={"/detection"}) if m.data.reason != "fault_injected"]
    answered = [d for d in dets if d.HasField("pixel")]
    assert answered
    for d in dets:
        rim = np.array([(p.x, p.y) for p in d.roi_rim], np.float32)
        assert len(rim) == 72 and np.all(np.isfinite(rim))
        assert cv2.contourArea(rim) > 1000  # px²: a real ellipse, not a degenerate one
        if d.HasField("pixel"):
            assert cv2.pointPolygonTest(rim, (d.pixel.x, d.pixel.y), False) >= 0


def test_flame_only_inside_the_interlock_in_the_log(run_c):
    from mission.runlog_read import iter_run

    _, out = run_c
    on = [m.data for m in iter_run(out / "run.mcap", topics={"/igniter/state"}) if m.data.flame_on]
    assert on, "the flame was never on"
    for st in on:
        assert st.interlock_ok and st.body_stationary and st.epmc_ok and not st.estop


def test_tf_follows_the_walks_and_arm_moves(run_c):
    """/tf is written during every body and arm move (the drivers' on_state), not only at their
    ends: the body's path in the log has no jump longer than 0.1 s of walking, and the log
    time between samples while moving stays near the 0.1 s period."""
    import math

    from mission.runlog_read import iter_run

    _, out = run_c
    path = []
    for m in iter_run(out / "run.mcap", topics={"/tf"}):
        body = next(t for t in m.data.transforms if t.child_frame_id == "body")
        path.append((m.log_time, body.translation.x, body.translation.y))
    steps = [(t1 - t0, math.hypot(x1 - x0, y1 - y0)) for (t0, x0, y0), (t1, x1, y1) in zip(path, path[1:])]
    walked = sum(d for _, d in steps)
    assert walked > 3.0  # three targets and the end pose, metres
    v_max = 0.8  # BodyConfig.max_speed
    assert max(d for _, d in steps) <= v_max * 0.1 + 0.03
    moving = [dt for dt, d in steps if d > 1e-4]
    assert len(moving) > walked / (v_max * 0.1) * 0.8
    assert max(moving) < 0.2e9


def test_interlock_denies_each_unsafe_condition(robot, core, task):
    from capm_field.arm_poses import flame_solution
    from capm_field.reachability import FlameSolver
    from sim_bench.bench_drivers import open_bench_drivers

    troi = TROI(1.0, 0.0, 0.25, "X")
    start = SE2(0.3, 0.0, 0.0)
    d = open_bench_drivers(robot, task, [troi], start, seed=1)
    try:
        body = d.body.state().pose
        mpoi = (0.95, 0.05)
        sol = flame_solution(robot, FlameSolver(robot, task), core.maps, body, mpoi)
        assert sol is not None
        assert d.arm.move_joints(sol.q, 20.0).ok
        il = IgnitionInterlock(d, robot, task, mpoi)
        il.anchor()
        assert il.check().ok, il.check().reasons
        # Aimed elsewhere: EPMC fails for this MPOI.
        assert "epmc" in " ".join(IgnitionInterlock(d, robot, task, (0.5, 0.6)).check().reasons)
        # E-stop pressed.
        d.body.sim.press_estop()
        assert "estop" in il.check().reasons
        d.body.sim.release_estop()
        assert il.check().ok
        # Body displaced since ignition started (slip): not stationary.
        d.body.sim.inject_slip(0.05, 0.0)
        d.body.move_to(SE2(body.x, body.y, body.yaw), 10.0)
        st = il.check()
        assert not st.ok
    finally:
        d.close()


def test_wire_level_bench_mission(tmp_path):
    """The same mission through the real adapters: ZenohBody over loopback zenoh, CanArm and
    CanIgniter over the python-can virtual bus, against the simulated robot sides."""
    m = tmp_path / "w.yaml"
    m.write_text(
        "field:\n  trois:\n    - {id: A, x: 1.0, y: 0.3, r: 0.22}\nstart: {x: 0, y: 0}\n"
        f"drivers: {{kind: bench, seed: 2, transport: wire}}\noutput: {{dir: {tmp_path / 'out'}}}\n"
    )
    r = subprocess.run(CLI + ["run", str(m), "--quiet"], capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, r.stderr
    s = json.loads((tmp_path / "out" / "summary.json").read_text())
    # Flamed means the interlock saw EPMC hold for the detected MPOI through the real adapters;
    # how close the detection is to the truth is the detector bench's business.
    assert s["targets"][0]["flamed"], s["targets"][0]["reason"]
    from mission.log_checks import check_ignition_invariant

    chk = check_ignition_invariant(tmp_path / "out" / "run.mcap")
    assert chk.ok and chk.flame_on_samples > 0


def test_field_planner_mission(tmp_path):
    """planner: field through the executive: every target handled, the interlock held, and no
    walk to a midpoint x_kmax (fewer body moves than per-target CAPM on the same field)."""
    from mission.log_checks import check_ignition_invariant

    moves, procs = {}, {}
    for planner in ("field", "c"):  # the two runs side by side
        m = tmp_path / f"{planner}.yaml"
        m.write_text(MISSION.format(planner=planner, seed=5, out=tmp_path / planner))
        procs[planner] = subprocess.Popen(CLI + ["run", str(m), "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        for proc in procs.values():
            _, err = proc.communicate(timeout=240)
            assert proc.returncode == 0, err
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    for planner in ("field", "c"):
        out = tmp_path / planner
        s = json.loads((out / "summary.json").read_text())
        assert all(t["flamed"] or t["reason"] for t in s["targets"])
        assert check_ignition_invariant(out / "run.mcap").ok
        moves[planner] = [t["body_moves"] for t in s["targets"]]
    # Per-target CAPM walks x_k0 → x_b,k1 (→ x_b,k3) → x_kmax: ≥ 2 moves a target. The field
    # planner's x_kmax is the flame pose: at most the walk to x_b,k1 and a reposition.
    assert all(m <= 2 for m in moves["field"])
    assert all(m >= 2 for m in moves["c"] if m)  # (a skipped target may have fewer)
    assert sum(moves["field"]) <= sum(moves["c"])


def test_a_detector_failure_is_kept_in_the_run_log(tmp_path):
    """A bug inside the detector (here: stage 1 raises) must neither stop the mission nor pass
    unseen: the target is not flamed (no MPOI), the run ends normally, and the traceback is a
    /log line of run.mcap, named after the detector's logger, and on the console."""
    m = tmp_path / "f.yaml"
    m.write_text(
        "field:\n  trois:\n    - {id: A, x: 1.0, y: 0.3, r: 0.22}\nstart: {x: 0, y: 0}\n"
        f"drivers: {{kind: bench, seed: 2}}\noutput: {{dir: {tmp_path / 'out'}}}\n"
    )
    code = (
        "import sys, capm_field.detector as d\n"
        "def boom(*a, **k):\n    raise RuntimeError('injected detector bug')\n"
        "d._detect = boom\n"
        "from capm_field.cli import main\n"
        f"sys.exit(main(['run', {str(m)!r}, '--quiet']))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=180, check=False)
    assert r.returncode == 0, r.stderr
    assert "injected detector bug" in r.stderr
    s = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert not s["targets"][0]["flamed"] and s["targets"][0]["reason"]
    from mcap_protobuf.decoder import DecoderFactory

    with open(tmp_path / "out" / "run.mcap", "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        logs = [m for _, _, _, m in reader.iter_decoded_messages(topics=["/log"])]
    bug = [x for x in logs if x.name == "capm_field.detector"]
    assert bug and "RuntimeError: injected detector bug" in bug[0].message and bug[0].level == 4, [x.message[:80] for x in logs]
