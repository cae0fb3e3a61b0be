import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capm_field.annulus import via_cost
from capm_field.config import TaskConfig
from capm_field.errors import UserError
from capm_field.geometry import SE2
from capm_field.keystates import TROI
from capm_field.planners import make_planner
from capm_field.reachability import RadialSet

TROI0 = TROI(0.0, 0.0, 0.25)


def _line(L: float) -> tuple[SE2, SE2]:
    return SE2(-L / 2, 0.0, 0.0), SE2(L / 2, 0.0, 0.0)


def test_deterministic_on_a_straight_path_costs_two_moves_plus_length(core):
    S, E = _line(3.0)
    for tb in ("first", "uniform", "nearest"):
        from capm_field.planners import PlannerOptions

        plan = make_planner("a", core, PlannerOptions(tiebreak=tb), seed=1).plan(S, E, TROI0)
        x1 = plan.x_b_k1
        assert abs(x1.y) < 1e-9  # the stop is on the path
        assert core.rm.contains(math.hypot(x1.x, x1.y))  # … inside R_m(X_w)
        assert plan.expected_cost == pytest.approx(2 + core.task.gamma * 3.0)
        assert [k.label for k in plan.key_states] == ["x_k0", "x_b,k1", "x_e,k3", "x_kmax"]


def test_decoupled_collinear_case_costs_three_moves_plus_length(core):
    S, E = _line(3.0)
    plan = make_planner("b", core).plan(S, E, TROI0)
    # R_o and R_m both meet the straight path, so observe, reposition and leave all lie on it.
    assert plan.expected_cost == pytest.approx(3 + core.task.gamma * 3.0, abs=1e-3)
    assert [k.label for k in plan.key_states] == ["x_k0", "x_b,k1", "x_e,k2", "x_b,k3", "x_e,k3", "x_kmax"]


def test_capm_maximises_p_on_the_path_and_beats_decoupled(core):
    S, E = _line(3.0)
    c = make_planner("c", core).plan(S, E, TROI0)
    b = make_planner("b", core).plan(S, E, TROI0)
    # Collinear: c_0 + c_u = 2 + γL and c_l = 3 + γL, so E[c] = 3 + γL − p.
    assert c.expected_cost == pytest.approx(3 + core.task.gamma * 3.0 - c.p_upper, abs=2e-3)
    assert c.expected_cost < b.expected_cost
    # p at the chosen stop is (near) the best p over R_o ∩ path.
    from capm_field.probability import p_closed_form

    ro = core.ro(0.25)
    xs = np.linspace(-1.5, 1.5, 3001)
    on = ro.contains(np.abs(xs))
    best_p = float(np.max(p_closed_form(np.abs(xs[on]), core.task.sigma(0.25), core.rm)))
    assert c.p_upper == pytest.approx(best_p, abs=0.01)


def test_after_observation_branches(core):
    S, E = _line(3.0)
    planner = make_planner("c", core)
    plan = planner.plan(S, E, TROI0)
    x1 = plan.x_b_k1
    # An MPOI right at X_w is reachable from x_b,k1 → upper branch, two moves.
    near = np.array(TROI0.xy)
    if core.regions.in_R_m(x1, near):
        out = planner.after_observation(plan, near)
        assert out.branch == "upper" and out.success and out.body_moves == 2
    # An MPOI far behind → lower branch: x_b,k3 ∈ R_m(X̄_w), reposition counted as a move.
    far = np.array([1.2, 1.0])
    out = planner.after_observation(plan, far)
    assert out.branch == "lower" and out.success and out.body_moves == 3
    k3 = next(k for k in out.key_states if k.label == "x_b,k3").body
    assert core.regions.in_R_m(k3, far)


def test_replan_is_optimal_against_brute_force(core):
    rng = np.random.default_rng(2)
    task = core.task
    for _ in range(20):
        P, E, X = rng.uniform(-2, 2, 2), rng.uniform(-2, 2, 2), rng.uniform(-1, 1, 2)
        val, P3 = via_cost(P[None], E, X, core.rm, task)
        rr, th = np.meshgrid(np.linspace(*core.rm.intervals[0], 120), np.linspace(-math.pi, math.pi, 720))
        C = X + np.stack([rr.ravel() * np.cos(th.ravel()), rr.ravel() * np.sin(th.ravel())], 1)
        brute = 2 + task.gamma * (np.linalg.norm(C - P, axis=1) + np.linalg.norm(E - C, axis=1))
        if core.rm.contains(np.linalg.norm(E - X)):
            brute = np.minimum(brute, 1 + task.gamma * np.linalg.norm(E - P))
        assert val[0] <= brute.min() + 1e-3
        assert val[0] >= brute.min() - 0.02


@settings(max_examples=60, deadline=None)
@given(
    px=st.floats(-2, 2), py=st.floats(-2, 2), ex=st.floats(-2, 2), ey=st.floats(-2, 2),
    a=st.floats(0.1, 0.8), w=st.floats(0.05, 0.8),
)
def test_via_cost_squared_form_is_midpoint_projection(px, py, ex, ey, a, w):
    task = TaskConfig(gamma=2.0, distance_form="squared")
    rs = RadialSet(((a, a + w),))
    P, E, X = np.array([px, py]), np.array([ex, ey]), np.zeros(2)
    val, P3 = via_cost(P[None], E, X, rs, task)
    rr, th = np.meshgrid(np.linspace(a, a + w, 60), np.linspace(-math.pi, math.pi, 360))
    C = np.stack([rr.ravel() * np.cos(th.ravel()), rr.ravel() * np.sin(th.ravel())], 1)
    brute = 2 + 2.0 * (np.sum((C - P) ** 2, 1) + np.sum((E - C) ** 2, 1))
    if rs.contains(np.linalg.norm(E)):
        brute = np.minimum(brute, 1 + 2.0 * np.sum((E - P) ** 2))
    assert val[0] <= brute.min() + 1e-6
    assert val[0] >= brute.min() - 0.05


def test_plans_are_deterministic_under_a_seed(core):
    S, E = _line(3.3)
    for name in "abc":
        p1 = make_planner(name, core, seed=4).plan(S, E, TROI(0.1, -0.2, 0.22))
        p2 = make_planner(name, core, seed=4).plan(S, E, TROI(0.1, -0.2, 0.22))
        assert p1 == p2


def test_bad_planner_and_radius_are_user_errors(core):
    with pytest.raises(UserError, match="unknown planner"):
        make_planner("z", core)
    with pytest.raises(UserError, match="positive"):
        make_planner("c", core).plan(*_line(3.0), TROI(0, 0, -0.1))


def test_bayes_planner_is_no_worse_than_capm_in_expectation(core):
    """c* minimises the true expected cost; with common MPOI draws its mean must not exceed c's."""
    rng = np.random.default_rng(9)
    cstar, capm = make_planner("cstar", core), make_planner("c", core)
    diffs = []
    for _ in range(6):
        X = rng.uniform(0, 3, 2)
        th = rng.uniform(-math.pi, math.pi)
        u = np.array([math.cos(th), math.sin(th)])
        L = rng.uniform(2.75, 4.75)
        S, E = X - L / 2 * u, X + L / 2 * u
        troi = TROI(float(X[0]), float(X[1]), float(rng.uniform(0.2, 0.3)))
        start, end = SE2(S[0], S[1], th), SE2(E[0], E[1], th)
        p_star, p_c = cstar.plan(start, end, troi), capm.plan(start, end, troi)
        mpois = X + rng.normal(scale=core.task.sigma(troi.r), size=(1500, 2))
        cs = np.mean([cstar.after_observation(p_star, m).cost for m in mpois])
        cc = np.mean([capm.after_observation(p_c, m).cost for m in mpois])
        assert all(cstar.after_observation(p_star, m).success for m in mpois[:200])
        diffs.append(cs - cc)
    assert np.mean(diffs) <= 0.0
    assert max(diffs) < 0.03  # never clearly worse on any geometry
