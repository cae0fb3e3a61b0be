import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from capm_field.bench import BenchSpec, run_bench
from capm_field.planners import PlannerOptions

CLI = [sys.executable, "-m", "capm_field.cli"]


def _strip(res: dict) -> dict:
    return {"results": res["results"], "eta_bc": res["eta_bc"]}


def test_bench_is_identical_under_a_seed_and_independent_of_workers(core):
    spec = BenchSpec(trials=40, seed=11)
    one = run_bench(core, spec, PlannerOptions(), workers=1, progress=False)
    two = run_bench(core, spec, PlannerOptions(), workers=2, progress=False)
    assert _strip(one) == _strip(two)
    other = run_bench(core, BenchSpec(trials=40, seed=12), PlannerOptions(), workers=1, progress=False)
    assert _strip(other) != _strip(one)


def test_bench_reproduces_table_shape(core):
    res = run_bench(core, BenchSpec(trials=150, seed=1), PlannerOptions(), workers=2, progress=False)
    by = {(r["planner"], r["path_length"]): r for r in res["results"]}
    lengths = sorted({r["path_length"] for r in res["results"]})
    assert all(by[("b", L)]["success_rate"] == 1.0 and by[("c", L)]["success_rate"] == 1.0 for L in lengths)
    assert all(by[("a", L)]["success_rate"] < 0.7 for L in lengths)
    assert all(by[("c", L)]["avg_cost"] < by[("b", L)]["avg_cost"] for L in lengths)
    assert all(e > 0 for e in res["eta_bc"]) and res["eta_bc"][0] > res["eta_bc"][-1]


def test_bench_cli_json(tmp_path):
    out = tmp_path / "b.json"
    r = subprocess.run(CLI + ["bench", "--trials", "10", "--seed", "2", "--json", str(out), "--quiet"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    data = json.loads(out.read_text())
    assert {(x["planner"], x["path_length"]) for x in data["results"]} == {(p, L) for p in "abc" for L in (2.75, 3.25, 3.75, 4.25, 4.75)}
    for x in data["results"]:
        assert 0 <= x["success_rate"] <= 1 and x["trials"] == 10 and x["avg_cost"] > 0
    assert set(data["plan_latency_ms"]["c"]) >= {"median", "p99"}
    assert "η_bc" in r.stdout and "[3.82]" in r.stdout


@pytest.mark.parametrize(
    "args, needle",
    [
        (["bench", "--planners", "a,q"], "unknown planner 'q'"),
        (["bench", "--radius-range=-0.2,0.3"], "--radius-range"),
        # the option is named, not the config key it sets (was "task.delta", "task: Value error, eps_min …")
        (["bench", "--delta", "0"], "error: --delta: Input should be greater than 0"),
        (["bench", "--delta", "1.5"], "error: --delta: Input should be less than or equal to 1"),
        (["bench", "--eps-min", "0.2", "--eps-max", "0.1"], "error: --eps-min (0.2) must not exceed --eps-max (0.1)"),
        (["regions", "--delta", "-1"], "error: --delta: Input should be greater than 0"),
        (["bench-fields", "--gamma", "inf"], "error: --gamma: Input should be a finite number"),
        (["bench", "--urdf", "/no/such/z1.urdf"], "URDF file not found"),
        (["regions", "--radius", "-0.3"], "--radius must be positive"),
        (["frobnicate"], "unknown command"),
        # output files that cannot be written are refused before any work (were tracebacks at the end)
        (["bench", "--trials", "2", "--json", "/no/such/dir/b.json"], "directory /no/such/dir does not exist"),
        (["bench-fields", "--json", "/no/such/dir/f.json"], "directory /no/such/dir does not exist"),
        (["bench-perception", "--scenes", "1", "--json", "/no/such/dir/p.json"], "directory /no/such/dir does not exist"),
        (["bench-drivers", "--json", "/no/such/dir/d.json"], "directory /no/such/dir does not exist"),
        (["regions", "--out", "/no/such/dir/r.png"], "directory /no/such/dir does not exist"),
        (["bench", "--trials", "2", "--json", "/"], "is a directory"),
        # a directory that refuses only the write itself (os.access says yes to root): was refused after the work
        (["bench-perception", "--scenes", "1", "--json", "/proc/capm-field.json"], "--json /proc/capm-field.json: cannot write there"),
        # a negative seed reached numpy (a traceback)
        (["bench", "--seed", "-1"], "--seed: must be in [0, 2**63 - 1]"),
        (["bench-fields", "--seed", "-1"], "--seed: must be in [0, 2**63 - 1]"),
        (["bench-perception", "--scenes", "1", "--seed", "-1"], "--seed: must be in [0, 2**63 - 1]"),
        (["bench-perception", "--scenes", "x"], "argument --scenes: not an integer"),
        # nan passed `v <= 0` (an AssertionError, an OverflowError), inf printed inf rows
        (["bench", "--trials", "2", "--lengths", "nan"], "--lengths must be positive finite numbers"),
        (["bench-fields", "--densities", "nan"], "--densities must be positive finite numbers"),
        (["bench-fields", "--densities", "1,inf"], "--densities must be positive finite numbers"),
        (["bench", "--trials", "2", "--lengths", "1e300"], "--lengths must be positive finite numbers ≤ 1e+06"),
        # an empty file name was taken for "not given"; a file where a directory should be
        (["bench-mission", "mission/examples/bench_demo.yaml", "--trials", "2", "--json", ""], "--json: empty file name"),
        (["bench", "--trials", "2", "--json", f"{__file__}/x.json"], f"{__file__} is a file, not a directory"),
        # 100 000 workers forked as many copies of the planning core; 0 ran one quietly
        (["bench", "--trials", "2", "--workers", "100000"], "--workers: must be in [1, 64]"),
        (["bench-fields", "--workers", "0"], "--workers: must be in [1, 64]"),
        (["bench-drivers", "--duration", "1e9", "--json", "/tmp/never.json"], "--duration must be in [0.5, 86400] s"),
        # found by a sweep of every option (session 57): tracebacks, or counts that ran on past any patience
        (["bench", "--trials", "2", "--planners", "a,a"], "--planners: 'a' given twice"),  # IndexError after the bench
        (["bench", "--trials", "2", "--planners", "a,,b"], "--planners: an empty item"),
        (["bench", "--trials", "10" + "0" * 29], "argument --trials: must be in [1, 1 000 000]"),
        (["bench-fields", "--troi", "10" + "0" * 29], "argument --troi: must be in [1, 5 000]"),  # numpy ValueError
        (["bench-fields", "--single-trials", "-1"], "argument --single-trials: must be in [0, 1 000 000]"),
        (["bench-fields", "--densities", "1e-300"], "--densities must be ≥ 0.001 weeds/m²"),
        (["bench-perception", "--scenes", "10" + "0" * 29], "argument --scenes: must be in [1, 100 000]"),  # OverflowError
        (["bench-perception", "--scenes", "1", "--distortion", "100,0,0,0"], "no NSV pose in any of the 1 scenes"),
        (["bench-mission", "mission/examples/bench_demo.yaml", "--trials", "10" + "0" * 29], "argument --trials: must be in [2, 1 000 000]"),
        (["bench-drivers", "--json", "/tmp/never.json", "--cutoff-trials", "0"], "argument --cutoff-trials: must be in [1, 10 000]"),
        (["regions", "--mpoi-offset", "1e308"], "--mpoi-offset must be a finite distance in [0, 10] m"),
        # an empty path was "not given" or the current directory (--annotate '' wrote into it)
        (["bench", "--trials", "2", "--urdf", ""], "argument --urdf: empty path"),
        (["detect", "--annotate", "", "tests/fixtures/plants/seedling.jpg"], "argument --annotate: empty path"),
        (["detect-replay", ""], "argument RUN.mcap: empty path"),
        (["review", "", "--rrd", "/tmp/never.rrd"], "argument run: empty path"),
        (["bench-mission", "mission/examples/bench_demo.yaml", "--summary", ""], "argument --summary: empty path"),
    ],
)
def test_bad_input_is_one_line_exit_2(cli_run, args, needle):
    r = cli_run(args + ["--quiet"] if args[0] == "bench" else args)
    assert r.returncode == 2
    assert needle in r.stderr
    assert "Traceback" not in r.stderr
    assert len([ln for ln in r.stderr.splitlines() if "error" in ln]) == 1


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--resolution", "0"], "--resolution must be in [0.001, 0.1] m"),  # was ZeroDivisionError
        (["--resolution", "-0.01"], "--resolution must be in [0.001, 0.1] m"),  # was IndexError
        (["--resolution", "1e-9"], "--resolution must be in [0.001, 0.1] m"),  # was a 25 GiB raster
        (["--resolution", "nan"], "--resolution must be in [0.001, 0.1] m"),
        (["--resolution", "0.001"], "cells across (limit 2000)"),
        (["--mpoi-offset", "nan"], "--mpoi-offset must be a finite distance"),  # was a PNG without R_m
        (["--mpoi-offset", "inf"], "--mpoi-offset must be a finite distance"),
    ],
)
def test_regions_refuses_a_bad_raster_before_drawing(cli_run, tmp_path, args, needle):
    out = tmp_path / "r.png"
    r = cli_run(["regions", "--out", str(out)] + args)
    assert r.returncode == 2 and needle in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not out.exists()


def test_bench_mission_help_has_its_whole_description():
    r = subprocess.run(CLI + ["bench-mission", "--help"], capture_output=True, text=True)
    assert r.returncode == 0
    assert "the planner bench on a mission's own geometry, to check a run against it." in " ".join(r.stdout.split())


# ---- bench-mission against a real run of the same mission ------------------------------------------
TINY = """\
name: tiny
planner: c
task: {{xi: 0.5}}
field:
  trois:
    - {{id: A, x: 1.0, y: 0.3, r: 0.22}}
    - {{id: B, x: 2.0, y: 0.8, r: 0.25}}
start: {{x: 0.0, y: 0.0, yaw: 0.0}}
end: {{x: 2.5, y: 1.0}}
drivers: {{kind: bench, seed: 5}}
output: {{dir: {out}, images: false}}
"""


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> tuple[Path, Path]:
    """(mission file, summary.json) of a two-weed `capm-field run` on the bench (~3 s)."""
    d = tmp_path_factory.mktemp("tiny")
    mission = d / "tiny.yaml"
    mission.write_text(TINY.format(out=d / "out"))
    r = subprocess.run(CLI + ["run", str(mission), "--quiet"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    summary = d / "out" / "summary.json"
    assert any(t["flamed"] for t in json.loads(summary.read_text())["targets"])
    return mission, summary


def test_bench_mission_compares_a_real_run_of_the_mission(tiny_run, tmp_path):
    """--summary always crashed (a loop variable overwrote the summary: TypeError)."""
    mission, summary = tiny_run
    out = tmp_path / "b.json"
    r = subprocess.run(CLI + ["bench-mission", str(mission), "--trials", "4", "--summary", str(summary), "--json", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    run = json.loads(summary.read_text())
    flamed = [t for t in run["targets"] if t["flamed"]]
    assert f"({len(flamed)}/2 flamed)" in r.stdout and "run:   energy per flamed weed" in r.stdout
    res = json.loads(out.read_text())
    assert [t["id"] for t in res["targets"]] and {t["id"] for t in res["targets"]} == {"A", "B"}
    assert res["run_energy_per_weed"] == pytest.approx(sum(t["energy"] for t in flamed) / len(flamed))
    assert res["run_success_rate"] == run["success_rate"]


def _set(path: list, value):
    """An edit of a summary: set (or, with value ..., delete) the entry at `path`."""
    def edit(s: dict) -> None:
        for k in path[:-1]:
            s = s[k]
        if value is ...:
            del s[path[-1]]
        else:
            s[path[-1]] = value
    return edit


def _other_mission(s: dict) -> None:
    s["name"] = "elsewhere"
    for t in s["targets"]:
        t["id"] = "X" + t["id"]


@pytest.mark.parametrize(
    "edit, needle",
    [
        (_set(["targets", 0, "energy"], ...), "energy is missing"),  # was KeyError after the bench
        (_set(["targets", 0, "energy"], "4.2"), "energy must be a finite number in [0, inf], got '4.2'"),  # numpy TypeError
        (_set(["targets", 0, "energy"], math.nan), "energy must be a finite number in [0, inf], got nan"),
        (_set(["targets", 0, "energy"], True), "energy must be a finite number in [0, inf], got True"),
        (_set(["success_rate"], ...), "success_rate is missing"),
        (_set(["success_rate"], 2), "success_rate must be a finite number in [0, 1], got 2"),
        (_set(["targets", 0, "flamed"], "yes"), "is not a target with an id and flamed"),
        (_set(["targets"], {}), "no list of targets"),
        # another mission's summary matched no id: "the run flamed no target"
        (_other_mission, "is from another mission: its 2 target(s), of mission 'elsewhere'"),
        (_set(["targets"], []), "is from another mission: its 0 target(s)"),
    ],
)
def test_bench_mission_refuses_a_bad_summary_in_one_line_before_the_bench(cli_run, tiny_run, tmp_path, edit, needle):
    mission, summary = tiny_run
    s = json.loads(summary.read_text())
    s["targets"][0]["flamed"] = True
    edit(s)
    bad = tmp_path / "summary.json"
    bad.write_text(json.dumps(s))
    r = cli_run(["bench-mission", str(mission), "--trials", "2", "--summary", str(bad)])
    assert r.returncode == 2 and needle in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not r.stdout  # refused before the bench printed anything
    if edit is _other_mission:
        assert "this mission 'tiny'" in r.stderr and str(mission) in r.stderr


def test_perception_failures_pools_several_seeds(tmp_path):
    """bench/perception_failures.py --seeds: each seed's cases under its own directory, one line
    per seed and a pooled line whose counts are the seeds' sums."""
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, str(root / "bench" / "perception_failures.py"), "--scenes", "2", "--seeds", "0,3",
                          "--bare-share", "0.25", "--save", "none", "--out", str(tmp_path / "pf"),
                          "--cache", str(tmp_path / "cache" / "{seed}")],
                         capture_output=True, text=True, timeout=300, cwd=root)
    assert out.returncode == 0, out.stderr
    rows = {s: json.loads((tmp_path / "pf" / f"seed_{s}" / "cases.json").read_text()) for s in (0, 3)}
    assert all(len(r) == 2 for r in rows.values())
    assert (tmp_path / "cache" / "3").is_dir()
    lines = out.stdout.splitlines()
    assert [ln.split(":")[0] for ln in lines if ln.startswith("seed ")] == ["seed 0", "seed 3"]
    pooled = next(ln for ln in lines if ln.startswith("pooled:"))
    n_weed = sum(r["kind"] != "bare" for rs in rows.values() for r in rs)
    assert f"weed {n_weed}:" in pooled, pooled
    # a --cache without '{seed}' is split per seed: seed 3 must not read seed 0's views (named by case index)
    again = subprocess.run([sys.executable, str(root / "bench" / "perception_failures.py"), "--scenes", "2", "--seeds", "0,3",
                            "--bare-share", "0.25", "--save", "none", "--out", str(tmp_path / "pf2"),
                            "--cache", str(tmp_path / "shared")], capture_output=True, text=True, timeout=300, cwd=root)
    assert again.returncode == 0, again.stderr
    assert sorted(p.name for p in (tmp_path / "shared").iterdir()) == ["0", "3"]
    for s in (0, 3):
        rows2 = json.loads((tmp_path / "pf2" / f"seed_{s}" / "cases.json").read_text())
        assert [(r["kind"], r["reason"], r["pixel"]) for r in rows2] == [(r["kind"], r["reason"], r["pixel"]) for r in rows[s]]


def test_bench_mission_names_a_directory_given_as_summary(cli_run, tiny_run, tmp_path):
    """A directory as --summary was "file not found"."""
    r = cli_run(["bench-mission", str(tiny_run[0]), "--trials", "2", "--summary", str(tmp_path)])
    assert r.returncode == 2 and "--summary: is a directory, not a summary file" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_the_output_probe_leaves_no_file_and_an_existing_file_as_it_was(tmp_path):
    """check_output tries a write where the file would go: nothing of it may remain."""
    from capm_field.errors import check_output

    check_output(str(tmp_path / "new.json"), "--json")
    assert list(tmp_path.iterdir()) == []
    old = tmp_path / "old.json"
    old.write_text("kept")
    check_output(str(old), "--json")
    assert old.read_text() == "kept" and list(tmp_path.iterdir()) == [old]
