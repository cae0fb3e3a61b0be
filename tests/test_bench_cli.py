import json
import subprocess
import sys

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
        (["bench", "--delta", "0"], "task.delta"),
        (["bench", "--delta", "1.5"], "task.delta"),
        (["bench", "--eps-min", "0.2", "--eps-max", "0.1"], "eps_min"),
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
        # a negative seed reached numpy (a traceback)
        (["bench", "--seed", "-1"], "--seed: must be in [0, 2**63 - 1]"),
        (["bench-fields", "--seed", "-1"], "--seed: must be in [0, 2**63 - 1]"),
        (["bench-perception", "--scenes", "1", "--seed", "-1"], "--seed: must be in [0, 2**63 - 1]"),
        (["bench-perception", "--scenes", "x"], "--scenes: invalid int value"),
    ],
)
def test_bad_input_is_one_line_exit_2(args, needle):
    r = subprocess.run(CLI + args + ["--quiet"] if args[0] == "bench" else CLI + args, capture_output=True, text=True)
    assert r.returncode == 2
    assert needle in r.stderr
    assert "Traceback" not in r.stderr
    assert len([ln for ln in r.stderr.splitlines() if "error" in ln]) == 1
