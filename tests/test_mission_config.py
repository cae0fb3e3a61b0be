import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from capm_field.keystates import TROI
from mission.config import MissionError, load_mission
from mission.ordering import order_trois

EXAMPLES = Path(__file__).resolve().parents[1] / "mission" / "examples"
CLI = [sys.executable, "-m", "capm_field.cli"]

GOOD = """\
field:
  trois:
    - {x: 1.0, y: 2.0, r: 0.2}
start: {x: 0, y: 0}
drivers: {kind: bench, seed: 3}
"""


def _write(tmp_path: Path, text: str, name: str = "m.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_examples_validate():
    for f in ("bench_demo.yaml", "hardware_template.yaml"):
        r = subprocess.run(CLI + ["validate", str(EXAMPLES / f)], capture_output=True, text=True, cwd=EXAMPLES)
        if f == "hardware_template.yaml":
            # The template points at a prescan file the user provides: exactly that is reported.
            assert r.returncode == 2 and "prescan.csv: prescan file not found" in r.stderr
        else:
            assert r.returncode == 0, r.stderr
    mission, trois = load_mission(EXAMPLES / "bench_demo.yaml")
    assert len(trois) >= 10 and mission.drivers.kind == "bench"


def test_good_minimal_mission_has_paper_defaults(tmp_path):
    mission, trois = load_mission(_write(tmp_path, GOOD))
    assert trois == [TROI(1.0, 2.0, 0.2, "T00")]
    assert mission.task.eps_min == 0.05 and mission.task.eps_max == 0.10 and mission.task.gamma == 2.0
    assert mission.robot.body.operating_height == 0.8
    assert mission.end_pose() == mission.start.se2()


@pytest.mark.parametrize(
    "text, expect",
    [
        (GOOD.replace("r: 0.2", "r: -0.2"), [":3: field.trois.0.r: Input should be greater than or equal to 0.001"]),
        (GOOD.replace("x: 1.0", "x: one"), [":3: field.trois.0.x: Input should be a valid number"]),
        (GOOD + "colour: red\n", [":6: colour: Extra inputs are not permitted"]),
        (GOOD.replace("kind: bench", "kind: moon"), [":5: drivers"]),
        (GOOD + "planner: z\n", [":6: planner: unknown planner 'z'"]),
        (GOOD + "task: {delta: 1.5, eps_min: 0.2, eps_max: 0.1}\n", [":6: task.delta"]),
        (GOOD + "task: {eps_min: 0.2, eps_max: 0.1}\n", [":6: task: eps_min (0.2) must not exceed eps_max (0.1)"]),
        ("field: {trois: []}\nstart: {x: 0, y: 0}\ndrivers: {kind: bench}\n", [":1: field: no TROIs"]),
        ("field: [\n", ["YAML syntax error"]),
        ("- a\n- b\n", ["must be a mapping"]),
        (GOOD.replace("start: {x: 0, y: 0}\n", ""), ["start: Field required"]),
        # found by a field-engineer audit of the docs: each was accepted, then failed mid-run
        (GOOD.replace("x: 1.0", "x: yes"), [":3: field.trois.0.x: a number is needed, not a yes/no value"]),
        (GOOD.replace("x: 1.0", "x: 1.0e+308"), [":3: field.trois.0.x: Input should be less than or equal to 10000"]),
        (GOOD.replace("seed: 3", "seed: -1"), [":5: drivers.seed: Input should be greater than or equal to 0"]),
        (GOOD.replace("seed: 3", "seed: 99999999999999999999999999999"), [":5: drivers.seed: Input should be less than or equal to 9223372036854775807"]),
        (GOOD.replace("x: 1.0, y: 2.0", "x: 8.54, y: 47.38"),  # lon/lat read as metres: a 48 m walk
         ["field: the walk from start to T00 is 48.1 m, more than the body covers"]),
        (GOOD.replace("seed: 3}", "seed: 3, faults: 'meteor@0'}"), [":5: drivers.faults: fault kind 'meteor' unknown"]),
        (GOOD.replace("seed: 3}", "seed: 3, faults: 'slip@4'}"), [":5: drivers.faults: fault slip: target index 4 outside 0..0"]),
    ],
)
def test_bad_missions_name_key_path_and_line(tmp_path, text, expect):
    p = _write(tmp_path, text)
    with pytest.raises(MissionError) as ei:
        load_mission(p)
    msg = str(ei.value)
    for e in expect:
        assert e in msg, msg


def test_every_problem_reported_at_once(tmp_path):
    text = GOOD.replace("r: 0.2", "r: -0.2") + "colour: red\nplanner: q\n"
    with pytest.raises(MissionError) as ei:
        load_mission(_write(tmp_path, text))
    assert len(ei.value.problems) == 3


def test_run_with_bad_mission_writes_nothing(cli_run, tmp_path):
    p = _write(tmp_path, GOOD.replace("r: 0.2", "r: 7"))
    out = tmp_path / "out"
    r = cli_run(["run", str(p), "--out", str(out), "--quiet"])
    assert r.returncode == 2 and "field.trois.0.r" in r.stderr and "Traceback" not in r.stderr
    assert not out.exists()
    r = cli_run(["run", str(tmp_path / "missing.yaml")])
    assert r.returncode == 2 and "not found" in r.stderr


def test_prescan_csv_and_geojson(tmp_path):
    (tmp_path / "p.csv").write_text("x,y,r,id\n1.0,2.0,0.25,A\n3,4,0.2,B\n")
    m = GOOD.replace("  trois:\n    - {x: 1.0, y: 2.0, r: 0.2}\n", "  prescan: p.csv\n")
    _, trois = load_mission(_write(tmp_path, m))
    assert [t.id for t in trois] == ["A", "B"] and trois[0].r == 0.25
    gj = {"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": {"type": "Point", "coordinates": [1.5, 0.5]}, "properties": {"radius": 0.3, "id": "G1"}}]}
    (tmp_path / "p.geojson").write_text(json.dumps(gj))
    _, trois = load_mission(_write(tmp_path, m.replace("p.csv", "p.geojson")))
    assert trois == [TROI(1.5, 0.5, 0.3, "G1")]
    (tmp_path / "bad.csv").write_text("x,y,r\n1,2,zero\n1,2,-1\n")
    with pytest.raises(MissionError) as ei:
        load_mission(_write(tmp_path, m.replace("p.csv", "bad.csv")))
    assert len(ei.value.problems) == 2 and "bad.csv:2" in str(ei.value)


def test_ordering_nearest_neighbour_two_opt_is_no_longer_than_nn():
    rng = np.random.default_rng(0)
    for _ in range(10):
        trois = [TROI(float(x), float(y), 0.2, f"T{i}") for i, (x, y) in enumerate(rng.uniform(0, 5, (12, 2)))]
        start, end = np.zeros(2), np.array([5.0, 5.0])
        order = order_trois(trois, start, end)
        assert sorted(t.id for t in order) == sorted(t.id for t in trois)

        def length(seq):
            pts = np.vstack([start, [t.xy for t in seq], end])
            return np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1))

        # 2-opt local optimum: no single reversal shortens the path.
        base = length(order)
        for i in range(len(order) - 1):
            for j in range(i + 1, len(order)):
                assert length(order[:i] + order[i : j + 1][::-1] + order[j + 1 :]) >= base - 1e-9


def _order_rebuilt_per_move(trois, start_xy, end_xy, max_rounds=50):
    """`order_trois` as first written (its path rebuilt after every 2-opt move): the reference the
    in-place version must reproduce move for move."""
    pts = np.array([t.xy for t in trois], float)
    n = len(trois)
    left, order, cur = np.ones(n, bool), [], np.asarray(start_xy, float)
    for _ in range(n):
        nxt = int(np.argmin(np.where(left, np.hypot(*(pts - cur).T), np.inf)))
        order.append(nxt)
        left[nxt] = False
        cur = pts[nxt]
    s0, e0 = np.asarray(start_xy, float), np.asarray(end_xy, float)
    for _ in range(max_rounds):
        improved = False
        for i in range(n - 1):
            j0 = i + 1
            while j0 < n:
                P = np.vstack([s0, pts[order], e0])
                a, b = P[i], P[i + 1]
                js = np.arange(j0, n)
                c, dd = P[js + 1], P[js + 2]
                delta = np.hypot(*(a - c).T) + np.hypot(*(b - dd).T) - np.hypot(*(a - b)) - np.hypot(*(c - dd).T)
                hit = np.flatnonzero(delta < -1e-12)
                if len(hit) == 0:
                    break
                j = int(js[hit[0]])
                order = order[:i] + order[i : j + 1][::-1] + order[j + 1 :]
                improved = True
                j0 = j + 1
        if not improved:
            break
    return [trois[i] for i in order]


def test_ordering_in_place_gives_the_reference_order():
    """The 2-opt keeps its path and leg lengths up to date in place (5000 TROIs: 7.0 → 1.8 s); the
    visit order is the one the rebuilt-per-move version gives, on spread, clustered and repeated points."""
    rng = np.random.default_rng(7)
    for k in range(40):
        n = int(rng.integers(2, 80))
        xy = rng.uniform(0, 8, (n, 2)) if k % 3 else np.round(rng.normal(3, 0.5, (n, 2)), 1)  # (rounded: repeats)
        trois = [TROI(float(x), float(y), 0.1, f"T{i}") for i, (x, y) in enumerate(xy)]
        start, end = rng.uniform(-1, 9, 2), rng.uniform(-1, 9, 2)
        assert [t.id for t in order_trois(trois, start, end)] == [t.id for t in _order_rebuilt_per_move(trois, start, end)]

def test_duplicate_keys_and_non_finite_numbers_are_errors(tmp_path):
    text = GOOD.replace("{x: 1.0,", "{x: .nan,") + "start: {x: 5, y: 0}\ntask: {gamma: .inf}\n"
    with pytest.raises(MissionError) as ei:
        load_mission(_write(tmp_path, text))
    msg = str(ei.value)
    assert ":6: start: key given twice (first on line 4)" in msg
    assert "field.trois.0.x: Input should be a finite number" in msg
    assert "task.gamma: Input should be a finite number" in msg


def test_hostile_yaml_is_refused_with_a_clear_error(tmp_path):
    """Deep nesting, an alias inside itself and an alias "bomb" (9 lines → 10⁹ nodes) are
    MissionErrors, not RecursionError tracebacks or a hang; anchors used normally still load."""
    bomb = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    bomb += [f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * 10) + "]" for k in range(1, 10)]
    for text, expect in (
        ("a: " + "[" * 5000 + "\n", "nested too deeply"),
        ("&a [*a]\n", "alias refers to a node that contains it"),
        ("\n".join(bomb) + "\n", "expand to more than"),
    ):
        with pytest.raises(MissionError) as ei:
            load_mission(_write(tmp_path, text))
        assert expect in str(ei.value)
    shared = GOOD.replace("- {x: 1.0, y: 2.0, r: 0.2}", "- &t {x: 1.0, y: 2.0, r: 0.2}\n    - *t")
    _, trois = load_mission(_write(tmp_path, shared))
    assert [(t.x, t.y, t.r) for t in trois] == [(1.0, 2.0, 0.2)] * 2


def test_malformed_prescan_files_are_reported_per_feature(tmp_path):
    m = GOOD.replace("  trois:\n    - {x: 1.0, y: 2.0, r: 0.2}\n", "  prescan: p.geojson\n")
    point = {"type": "Point", "coordinates": [1, 2]}
    feats = [1, None, {"geometry": {"type": "Point", "coordinates": "ab"}},
             {"geometry": point, "properties": {"r": True}}, {"geometry": {"type": "Point", "coordinates": ["1", 2]}, "properties": {"r": 0.2}},
             {"geometry": point, "properties": {"r": 0.2, "id": "ok"}}]
    (tmp_path / "p.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": feats}))
    with pytest.raises(MissionError) as ei:
        load_mission(_write(tmp_path, m))
    assert len(ei.value.problems) == 5 and "features[3].properties: need a numeric radius" in str(ei.value)
    (tmp_path / "p.geojson").write_text("[" * 100000)
    with pytest.raises(MissionError, match="nested too deeply"):
        load_mission(_write(tmp_path, m))
    (tmp_path / "p.csv").write_bytes(b"\xff\xfe\x00x")
    with pytest.raises(MissionError, match="cannot read the prescan file"):
        load_mission(_write(tmp_path, m.replace("p.geojson", "p.csv")))
    (tmp_path / "p.csv").write_text("\ufeffx,y,r,id\n1,2,0.2,A\n", encoding="utf-8")  # spreadsheet export
    _, trois = load_mission(_write(tmp_path, m.replace("p.geojson", "p.csv")))
    assert trois == [TROI(1.0, 2.0, 0.2, "A")]


def test_unusable_output_paths_and_summaries_are_clear_errors(cli_run, tmp_path):
    """`run --out` that cannot be created and `bench-mission --summary` that is not a summary
    end with exit 2 and one line, not a traceback (the summary is checked before the bench)."""
    p = _write(tmp_path, GOOD)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    r = cli_run(["run", str(p), "--out", str(blocker / "sub"), "--quiet"])
    assert r.returncode == 2 and "cannot create the output directory" in r.stderr and "Traceback" not in r.stderr
    for content in (b"\xff\xfe", b'{"targets": 5}', b"[]"):
        (tmp_path / "s.json").write_bytes(content)
        r = cli_run(["bench-mission", str(p), "--summary", str(tmp_path / "s.json")])
        assert r.returncode == 2 and "is not a capm-field run's summary.json" in r.stderr and "Traceback" not in r.stderr
        assert "bench: energy" not in r.stdout


def test_run_refuses_bad_faults_seeds_and_configs_before_writing_anything(cli_run, tmp_path):
    """A bad --faults or --seed is refused before the output exists (a leftover run.mcap used to
    block the corrected run); a hardware mission's zenoh config is checked by `run` as by
    `validate`, before any driver opens (was: exit 1 from the CAN bus, config never checked)."""
    p = _write(tmp_path, GOOD)
    for extra, msg in ((["--faults", "meteor@0"], "fault kind 'meteor' unknown"), (["--seed", "-1"], "must be in [0, 2**63 - 1]")):
        out = tmp_path / "out"
        r = cli_run(["run", str(p), "--out", str(out), "--quiet"] + extra)
        assert r.returncode == 2 and msg in r.stderr and "Traceback" not in r.stderr, r.stderr
        assert not out.exists()
    text = (EXAMPLES / "hardware_template.yaml").read_text().replace("prescan: prescan.csv", "trois: [{x: 1, y: 1, r: 0.2}]")
    hw = _write(tmp_path, text, "hw.yaml")
    (tmp_path / "zenoh-client.json5").write_text("{ not json5 [[[")
    out = tmp_path / "hwout"
    r = cli_run(["run", str(hw), "--out", str(out), "--quiet"])
    assert r.returncode == 2 and "drivers.zenoh.config_file" in r.stderr and ".rs:" not in r.stderr, r.stderr
    assert not out.exists()
    r = cli_run(["run", str(hw), "--out", str(out), "--quiet", "--seed", "1"])
    assert r.returncode == 2 and not out.exists()


def test_validate_opens_the_zenoh_config_of_a_hardware_mission(cli_run, tmp_path):
    """`validate` loads drivers.zenoh.config_file as a hardware run would: a missing file, a
    file that is not JSON5, or a certificate it names that is not there is an error (exit 2)."""
    text = (EXAMPLES / "hardware_template.yaml").read_text().replace("prescan: prescan.csv", "trois: [{x: 1, y: 1, r: 0.2}]")
    p = _write(tmp_path, text)
    r = cli_run(["validate", str(p)])
    assert r.returncode == 2 and "zenoh config file not found" in r.stderr
    (tmp_path / "zenoh-client.json5").write_text("{ not json5 [[[")
    r = cli_run(["validate", str(p)])
    assert r.returncode == 2 and "drivers.zenoh.config_file" in r.stderr and "Traceback" not in r.stderr
    (tmp_path / "zenoh-client.json5").write_text((EXAMPLES / "zenoh-client.json5").read_text())
    r = cli_run(["validate", str(p)])
    assert r.returncode == 2 and "names a missing file" in r.stderr and "ca.pem" in r.stderr
    (tmp_path / "zenoh-client.json5").write_text("{}")
    r = cli_run(["validate", str(p)])
    assert r.returncode == 0, r.stderr


def test_generated_ids_never_collide_and_directories_are_named(tmp_path):
    text = "field:\n  trois:\n    - {x: 1.0, y: 2.0, r: 0.2}\n    - {id: T00, x: 2.0, y: 2.0, r: 0.2}\nstart: {x: 0, y: 0}\ndrivers: {kind: bench}\n"
    _, trois = load_mission(_write(tmp_path, text))
    assert [t.id for t in trois] == ["T01", "T00"]
    (tmp_path / "d.yaml").mkdir()
    with pytest.raises(MissionError, match="is a directory, not a mission file"):
        load_mission(tmp_path / "d.yaml")


def test_validate_reads_the_tls_files_a_hardware_mission_names(cli_run, tmp_path):
    """Certificates and keys must be PEM of their kind and each key must go with its certificate:
    otherwise every TLS handshake on the robot would fail, found only there (was: 'ok' when the
    files merely existed)."""
    from sim_bench.dev_pki import make_dev_pki

    make_dev_pki(tmp_path / "certs", clients=("capm-commander", "capm-observer"))
    text = (EXAMPLES / "hardware_template.yaml").read_text().replace("prescan: prescan.csv", "trois: [{x: 1, y: 1, r: 0.2}]")
    p = _write(tmp_path, text)
    cfg = tmp_path / "zenoh-client.json5"
    cfg.write_text((EXAMPLES / "zenoh-client.json5").read_text())
    r = cli_run(["validate", str(p)])
    assert r.returncode == 0, r.stderr
    good = (tmp_path / "certs" / "capm-commander.key").read_bytes()
    (tmp_path / "certs" / "capm-commander.key").write_bytes((tmp_path / "certs" / "capm-observer.key").read_bytes())
    r = cli_run(["validate", str(p)])
    assert r.returncode == 2 and "does not go with" in r.stderr and "Traceback" not in r.stderr, r.stderr
    (tmp_path / "certs" / "capm-commander.key").write_bytes(good)
    (tmp_path / "certs" / "ca.pem").write_text("this is not a certificate\n")
    r = cli_run(["validate", str(p)])
    assert r.returncode == 2 and "is not a PEM certificate" in r.stderr, r.stderr


def test_huge_mission_file_is_refused_at_once(tmp_path):
    p = _write(tmp_path, GOOD + "#" * (5 * 2**20) + "\n")
    with pytest.raises(MissionError, match="MiB is not a mission file"):
        load_mission(p)


def test_validate_warns_of_an_unprotected_robot_link_and_checks_output_and_bitrate(cli_run, tmp_path):
    hw = "field: {trois: [{x: 1, y: 1, r: 0.2}]}\nstart: {x: 0, y: 0}\ndrivers:\n  kind: hardware\n" \
         "  zenoh: {connect: ['tcp/10.0.0.1:7447']}\n  can: {interface: virtual, channel: c0, bitrate: BR}\n"
    r = cli_run(["validate", str(_write(tmp_path, hw.replace("BR", "500000")))])
    assert r.returncode == 0 and "warning: drivers.zenoh: tcp/10.0.0.1:7447 without a config_file: no TLS" in r.stderr, r.stderr
    r = cli_run(["validate", str(_write(tmp_path, hw.replace("BR", "-5")))])
    assert r.returncode == 2 and "drivers.can.bitrate" in r.stderr
    (tmp_path / "afile").write_text("x")
    r = subprocess.run(CLI + ["validate", str(_write(tmp_path, GOOD + "output: {dir: afile}\n"))], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 2 and "output.dir" in r.stderr and "not a directory" in r.stderr


def test_mission_fault_list_takes_phase_and_at_s(tmp_path):
    """A fault list entry's `phase` and `at_s` reach the injector (`at_s` was accepted and then
    read nowhere; `phase` was refused as an unknown key)."""
    from sim_bench.faults import parse_faults

    p = tmp_path / "m.yaml"
    p.write_text(GOOD.replace("seed: 3", "seed: 3, faults: [{kind: slip, target: 0, phase: flame, at_s: 1.5, params: {dx: 0.1}}]"))
    mission, trois = load_mission(p)
    (f,) = parse_faults(mission.drivers.faults, len(trois))
    assert (f.kind, f.target, f.phase, f.params) == ("slip", 0, "flame", {"dx": 0.1, "at_s": 1.5})
    p.write_text(GOOD.replace("seed: 3", "seed: 3, faults: [{kind: slip, phase: sleep}]"))
    with pytest.raises(MissionError, match="phase"):
        load_mission(p)
    p.write_text(GOOD.replace("seed: 3", "seed: 3, faults: [{kind: slip, at_s: 1, params: {at_s: 2}}]"))
    with pytest.raises(MissionError, match="at_s given twice"):
        load_mission(p)


@pytest.mark.parametrize("text, expect", [
    ("x,x,y,r\n1,5,2,0.2\n", "bad.csv:1: column 'x' named twice"),  # DictReader kept the last x silently
    ("1,2,0.2\n3,4,0.2\n", "bad.csv:1: the first line must name the columns x, y, r"),  # was "field: no TROIs"
    ("x,y,r\n1_0,2,0.2\n", "bad.csv:2: need numeric columns x, y, r"),  # float() read 1_0 as 10
])
def test_prescan_csv_header_and_numbers_are_checked(tmp_path, text, expect):
    """Found by a fuzzing sweep: each of these loaded (or failed with a misleading line) before."""
    (tmp_path / "bad.csv").write_text(text)
    m = GOOD.replace("  trois:\n    - {x: 1.0, y: 2.0, r: 0.2}\n", "  prescan: bad.csv\n")
    with pytest.raises(MissionError, match=expect):
        load_mission(_write(tmp_path, m))


def test_ordering_a_second_time_reuses_the_tour_only_for_the_same_points(monkeypatch):
    """A run orders its TROIs when the mission file is checked and again when it starts (5 000 TROIs:
    ~2 s each): the second call reuses the tour; other points, start or end compute a new one."""
    import mission.ordering as ordering

    rng = np.random.default_rng(3)
    trois = [TROI(float(x), float(y), 0.2, f"T{i}") for i, (x, y) in enumerate(rng.uniform(0, 5, (30, 2)))]
    start, end = np.zeros(2), np.array([5.0, 5.0])
    first = order_trois(trois, start, end)
    calls = []
    real = ordering._tour
    monkeypatch.setattr(ordering, "_tour", lambda *a: calls.append(1) or real(*a))
    assert order_trois([TROI(t.x, t.y, t.r, t.id) for t in trois], start, end) == first and not calls
    moved = trois[:5] + [TROI(trois[5].x + 0.5, trois[5].y, 0.2, trois[5].id)] + trois[6:]
    assert sorted(t.id for t in order_trois(moved, start, end)) == sorted(t.id for t in trois) and len(calls) == 1
    assert order_trois(trois, start, np.array([0.0, 5.0])) == _order_rebuilt_per_move(trois, start, np.array([0.0, 5.0]))
    assert len(calls) == 2
