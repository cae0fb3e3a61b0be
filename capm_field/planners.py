"""Planners for one TROI (paper §IV-F and §V-A): (a) deterministic, (b) decoupled, (c) CAPM.

All three return a `Plan` (key states as data) before observation, and `after_observation`
turns it into the executed key states once the MPOI X̄_w is known (the re-plan: minimise c_l
s.t. x_b,k3 ∈ R_m(X̄_w)).

Body placement works on the arm-base position P (the regions are annuli around targets in that
frame) and converts to body poses at the end. Yaw policy: at x_b,k1 the body faces X_w, at x_b,k3
it faces X̄_w, so the target is straight ahead of the arm (Z1 joint 1 covers ±150°); start and end
poses keep their given yaw. The optimisation is over positions; the orientation term β(1−|q·q|)
of d is charged in the reported costs but not optimised (β = 0 by default; the paper gives none).

  (a) min c(x_k0, x_b,k1) + c(x_b,k1, x_kmax) s.t. x_b,k1 ∈ R_m(X_w); no observation.
  (b) always observe then reposition: min c_0 + c_l s.t. x_b,k1 ∈ R_o, x_b,k3 ∈ R_m(X_w).
  (c) CAPM, eq. 11: min c_0 + p(x_b,k1)·c_u + (1 − p(x_b,k1))·c_l over the same sets.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from . import energy
from .annulus import best_stop, via_cost
from .config import TaskConfig
from .errors import UserError
from .geometry import SE2
from .keystates import TROI, KeyState, Outcome, Plan
from .probability import p_closed_form
from .reachability import RadialSet, ReachabilityMaps, Regions
from .robot_model import RobotModel

PLANNERS = ("a", "b", "c")  # the paper's three (Table I)
ALL_PLANNERS = ("a", "b", "c", "cstar")
Tiebreak = Literal["first", "uniform", "nearest"]


@dataclass(frozen=True)
class PlannerOptions:
    tiebreak: Tiebreak = "uniform"  # planner (a): which of the equally short stops it takes
    coarse_radii: int = 10
    coarse_angles: int = 36
    refine_rounds: int = 3


class PlanningCore:
    """Robot model + reachability maps + task: what every planner needs."""

    def __init__(self, robot: RobotModel, maps: ReachabilityMaps, task: TaskConfig):
        self.robot = robot
        self.maps = maps
        self.task = task
        self.regions = Regions(robot, maps)
        # Plan inside the maps: the body's placement error, plus a quarter bin for R_m and 1.5
        # bins for R_o, whose inner edge (view rays grazing the body) is the least sharp.
        tol = robot.cfg.body.position_tolerance
        self.margin = 0.25 * maps.manip.step + tol
        self.margin_o = 1.5 * maps.manip.step + tol
        self.rm: RadialSet = maps.manip.radial_set(None).shrink(self.margin)
        if self.rm.empty:
            raise UserError("R_m is empty: the nozzle cannot reach the ground within [ε_min, ε_max] from any pose (check robot and task)")
        self._ro_cache: dict[float, RadialSet] = {}
        nonempty = [r for r, m in zip(maps.troi_radii, maps.observe) if np.isfinite(m.lo).any()]
        if not nonempty:
            raise UserError("R_o is empty for every TROI radius: the camera cannot satisfy NSV (check camera and δ)")
        self.r_min_observable = float(min(nonempty))

    def effective_radius(self, r_w: float) -> float:
        """TROI radius used for R_o: radii below the smallest observable one are inflated to it
        (the larger disc still contains the MPOI); above the mapped range is an error."""
        if r_w <= 0:
            raise UserError(f"TROI radius must be positive, got {r_w}")
        if r_w > float(self.maps.troi_radii[-1]) + 1e-9:
            raise UserError(f"TROI radius {r_w} m exceeds the largest mapped radius {self.maps.troi_radii[-1]:.2f} m")
        return max(r_w, self.r_min_observable)

    def ro(self, r_w: float) -> RadialSet:
        r = self.effective_radius(r_w)
        key = round(r, 4)
        if key not in self._ro_cache:
            # Conservative between mapped radii: feasible for both neighbours of r_w.
            sets = [self.maps.observe_map(x).radial_set(None) for x in self.maps.bracketing_radii(r)]
            rs = sets[0]
            for other in sets[1:]:
                rs = rs.intersect(other)
            self._ro_cache[key] = rs.shrink(self.margin_o)
        return self._ro_cache[key]

    def base_xy(self, body: SE2) -> np.ndarray:
        return self.robot.arm_base_xy(body)

    def facing(self, P: np.ndarray, target: np.ndarray) -> SE2:
        """Body pose whose arm base is at P, facing `target`."""
        yaw = math.atan2(target[1] - P[1], target[0] - P[0]) if np.linalg.norm(target - P) > 1e-9 else 0.0
        return self.robot.body_for_arm_base(P, yaw)


class BasePlanner:
    name = "?"

    def __init__(self, core: PlanningCore, options: PlannerOptions | None = None, seed: int = 0):
        self.core = core
        self.task = core.task
        self.opt = options or PlannerOptions()
        self.rng = np.random.default_rng(seed)

    # ---- helpers ---------------------------------------------------------------------------
    def _sigma(self, troi: TROI) -> float:
        return self.task.sigma(troi.r)

    def _optimise_k1(self, X: np.ndarray, ro: RadialSet, objective, coarse_objective=None, seeds: int = 1) -> tuple[np.ndarray, dict]:
        """argmin over P1 ∈ annulus(X, ro) of objective(ρ, α) → (values, terms): a coarse polar grid
        (ranked by `coarse_objective` when the objective is expensive), then local refinement of
        the best `seeds` grid points."""
        best_val, best = math.inf, None
        alphas = np.linspace(-math.pi, math.pi, self.opt.coarse_angles, endpoint=False)
        for a, b in ro.intervals:
            R, A = np.meshgrid(np.linspace(a, b, self.opt.coarse_radii), alphas, indexing="ij")
            rho, alpha = R.ravel(), A.ravel()
            val, terms = (coarse_objective or objective)(rho, alpha)
            for i in np.argsort(val)[:seeds]:
                dr, da = (b - a) / max(self.opt.coarse_radii - 1, 1), 2 * math.pi / self.opt.coarse_angles
                r0, a0 = rho[i], alpha[i]
                v_i, t_i = val[i], {k: v[i] for k, v in terms.items()}
                if coarse_objective is not None:
                    v, t = objective(np.array([r0]), np.array([a0]))
                    v_i, t_i = v[0], {k: x[0] for k, x in t.items()}
                for _ in range(self.opt.refine_rounds):
                    Rr, Aa = np.meshgrid(np.clip(r0 + np.linspace(-dr, dr, 7), a, b), a0 + np.linspace(-da, da, 7), indexing="ij")
                    rr, aa = Rr.ravel(), Aa.ravel()
                    v, t = objective(rr, aa)
                    j = int(np.argmin(v))
                    if v[j] <= v_i:
                        r0, a0, v_i, t_i = rr[j], aa[j], v[j], {k: x[j] for k, x in t.items()}
                    dr, da = dr / 3, da / 3
                if v_i < best_val:
                    best_val = float(v_i)
                    best = (np.array([X[0] + r0 * math.cos(a0), X[1] + r0 * math.sin(a0)]), {k: float(x) for k, x in t_i.items()})
        assert best is not None
        P1, terms = best
        terms["objective"] = best_val
        return P1, terms

    def _paper_objective(self, S: np.ndarray, E: np.ndarray, X: np.ndarray, sigma: float, use_p: bool):
        """Eq. 11: c_0 + p·c_u + (1 − p)·c_l with c_l against X_w (use_p False: c_0 + c_l, planner b)."""
        g, task, rm = self.task.gamma, self.task, self.core.rm

        def objective(rho: np.ndarray, alpha: np.ndarray) -> tuple[np.ndarray, dict]:
            P = X + np.stack([rho * np.cos(alpha), rho * np.sin(alpha)], 1)
            c0 = 1.0 + g * energy.travel(P - S, task)
            cl, _ = via_cost(P, E, X, rm, task)
            if not use_p:
                return c0 + cl, {"c0": c0, "cl": cl, "p": np.zeros_like(c0)}
            p = p_closed_form(rho, sigma, rm)
            cu = 1.0 + g * energy.travel(E - P, task)
            return c0 + p * cu + (1 - p) * cl, {"c0": c0, "cl": cl, "cu": cu, "p": p}

        return objective

    def _replan_k3(self, P1: np.ndarray, E: np.ndarray, mpoi: np.ndarray) -> np.ndarray:
        """The re-plan: x_b,k3 = argmin c_l s.t. x_b,k3 ∈ R_m(X̄_w)."""
        _, P3 = via_cost(P1[None], E, mpoi, self.core.rm, self.task)
        return P3[0]

    def _flame_pose_ok(self, body: SE2, mpoi: np.ndarray) -> bool:
        return bool(self.core.regions.in_R_m(body, mpoi))

    # ---- API -------------------------------------------------------------------------------
    def plan(self, start: SE2, end: SE2, troi: TROI) -> Plan:
        raise NotImplementedError

    def after_observation(self, plan: Plan, mpoi_xy: tuple[float, float] | np.ndarray) -> Outcome:
        """Choose the branch once X̄_w is known and return the executed key states and their cost."""
        mpoi = np.asarray(mpoi_xy, dtype=float)
        x1 = plan.x_b_k1
        seq = [plan.state("x_k0"), plan.state("x_b,k1"), plan.state("x_e,k2")]
        upper = self.name != "b" and self._flame_pose_ok(x1, mpoi)
        if upper:
            seq += [KeyState("x_e,k3", x1, "flame", tuple(mpoi))]
            bodies, forced, branch = [plan.start, x1, plan.end], set(), "upper"
        else:
            P3 = self._replan_k3(self.core.base_xy(x1), self.core.base_xy(plan.end), mpoi)
            x3 = self.core.facing(P3, mpoi)
            seq += [KeyState("x_b,k3", x3), KeyState("x_e,k3", x3, "flame", tuple(mpoi))]
            bodies, forced, branch = [plan.start, x1, x3, plan.end], {2}, "lower"
        seq.append(KeyState("x_kmax", plan.end))
        cost = energy.path_cost(bodies, self.task, forced)
        moves = sum(1 for i in range(len(bodies) - 1) if (i + 1) in forced or bodies[i].distance(bodies[i + 1]) > 1e-9 or bodies[i].yaw != bodies[i + 1].yaw)
        flame_body = seq[-2].body
        return Outcome(self.name, branch, tuple(k for k in seq if k is not None), cost, moves, self._flame_pose_ok(flame_body, mpoi))


class DeterministicPlanner(BasePlanner):
    """(a) Assume X̄_w = X_w: one stop in R_m(X_w) on the way, flame there without looking."""

    name = "a"

    def plan(self, start: SE2, end: SE2, troi: TROI) -> Plan:
        S, E, X = self.core.base_xy(start), self.core.base_xy(end), np.array(troi.xy)
        P1 = best_stop(S, E, X, self.core.rm, self.task, self.opt.tiebreak, self.rng)
        x1 = self.core.facing(P1, X)
        cost = energy.path_cost([start, x1, end], self.task)
        ks = (KeyState("x_k0", start), KeyState("x_b,k1", x1), KeyState("x_e,k3", x1, "flame", troi.xy), KeyState("x_kmax", end))
        return Plan(self.name, troi, start, end, ks, 1.0, cost, None, {"c0": energy.cost(start, x1, self.task), "cu": energy.cost(x1, end, self.task)})

    def after_observation(self, plan: Plan, mpoi_xy) -> Outcome:
        """No observation: the plan runs as is; success iff x_b,k1 ∈ R_m(true X̄_w)."""
        mpoi = np.asarray(mpoi_xy, dtype=float)
        x1 = plan.x_b_k1
        cost = energy.path_cost([plan.start, x1, plan.end], self.task)
        return Outcome(self.name, "blind", plan.key_states, cost, 2, self._flame_pose_ok(x1, mpoi))


class _ObservingPlanner(BasePlanner):
    use_p = True

    def _objective(self, S: np.ndarray, E: np.ndarray, X: np.ndarray, troi: TROI, sigma: float):
        return self._paper_objective(S, E, X, sigma, self.use_p)

    def _coarse(self, S: np.ndarray, E: np.ndarray, X: np.ndarray, sigma: float) -> tuple:
        """(coarse objective, number of refined seeds): the objective itself, one seed."""
        return None, 1

    def plan(self, start: SE2, end: SE2, troi: TROI) -> Plan:
        S, E, X = self.core.base_xy(start), self.core.base_xy(end), np.array(troi.xy)
        ro = self.core.ro(troi.r)
        sigma = self._sigma(troi)
        P1, terms = self._optimise_k1(X, ro, self._objective(S, E, X, troi, sigma), *self._coarse(S, E, X, sigma))
        x1 = self.core.facing(P1, X)
        P3 = self._replan_k3(P1, E, X)
        x3 = self.core.facing(P3, X)
        p = float(terms.get("p", 0.0))
        r_eff = self.core.effective_radius(troi.r)
        ks = [KeyState("x_k0", start), KeyState("x_b,k1", x1), KeyState("x_e,k2", x1, "observe", troi.xy, r_eff)]
        if self.use_p:
            ks.append(KeyState("x_e,k3", x1, "flame", troi.xy))
        else:
            ks += [KeyState("x_b,k3", x3), KeyState("x_e,k3", x3, "flame", troi.xy)]
        ks.append(KeyState("x_kmax", end))
        terms.update({"r_eff": r_eff, "sigma": sigma})
        return Plan(self.name, troi, start, end, tuple(ks), p, terms["objective"], x3, terms)


class DecoupledPlanner(_ObservingPlanner):
    """(b) Observe from R_o, then always reposition into R_m(X̄_w) (lower branch only)."""

    name = "b"
    use_p = False


class CapmPlanner(_ObservingPlanner):
    """(c) CAPM: choose x_b,k1 ∈ R_o minimising c_0 + p(x_b,k1)·c_u + (1 − p(x_b,k1))·c_l (eq. 11)."""

    name = "c"
    use_p = True


class BayesPlanner(_ObservingPlanner):
    """c*: x_b,k1 ∈ R_o minimising the true expected cost over the MPOI distribution,

        E[c] = c_0 + E_X̄w[ 1[x_b,k1 ∈ R_m(X̄_w)]·c_u + 1[x_b,k1 ∉ R_m(X̄_w)]·c_l*(x_b,k1, X̄_w) ],

    where c_l* is the cost of the re-plan that will actually happen for that MPOI (min over
    x_b,k3 ∈ R_m(X̄_w)), not the paper's stand-in c_l against X_w. The expectation is a fixed
    quasi-Monte-Carlo quadrature (scrambled Sobol, `n_quad` points) of the prior N(X_w, Σ_w),
    optionally restricted to the TROI (`in_troi`), so plans are deterministic.
    """

    name = "cstar"

    def __init__(self, core: PlanningCore, options: PlannerOptions | None = None, seed: int = 0, n_quad: int = 32, in_troi: bool = False):
        super().__init__(core, options, seed)
        from scipy.stats import qmc

        u = qmc.Sobol(d=2, scramble=True, seed=12345).random(n_quad)
        self._u = np.clip(u, 1e-6, 1 - 1e-6)
        self.in_troi = in_troi

    def _coarse(self, S: np.ndarray, E: np.ndarray, X: np.ndarray, sigma: float) -> tuple:
        # The true expectation is ~30× dearer than eq. 11, whose landscape is close: rank the grid
        # with eq. 11 and refine its two best points with the true expectation (four gave the
        # same expected cost on 120 cases at twice the time).
        return self._paper_objective(S, E, X, sigma, True), 2

    def _mpoi_quadrature(self, X: np.ndarray, sigma: float, r_w: float) -> np.ndarray:
        """Quadrature points of the MPOI prior (polar: Rayleigh radius, uniform angle)."""
        q = self._u[:, 0]
        if self.in_troi:  # Rayleigh radius truncated at r_w
            q = q * (1.0 - math.exp(-(r_w**2) / (2 * sigma**2)))
        rad = sigma * np.sqrt(-2.0 * np.log1p(-q))
        ang = 2 * math.pi * self._u[:, 1]
        return X + np.stack([rad * np.cos(ang), rad * np.sin(ang)], 1)

    def _objective(self, S: np.ndarray, E: np.ndarray, X: np.ndarray, troi: TROI, sigma: float):
        g, task, rm = self.task.gamma, self.task, self.core.rm
        M = self._mpoi_quadrature(X, sigma, troi.r)
        m = len(M)

        def objective(rho: np.ndarray, alpha: np.ndarray) -> tuple[np.ndarray, dict]:
            P = X + np.stack([rho * np.cos(alpha), rho * np.sin(alpha)], 1)
            n = len(P)
            c0 = 1.0 + g * energy.travel(P - S, task)
            cu = 1.0 + g * energy.travel(E - P, task)
            hit = rm.contains(np.linalg.norm(P[:, None, :] - M[None], axis=2))  # (n, m)
            cost = np.where(hit, cu[:, None], 0.0)
            miss = np.flatnonzero(~hit.ravel())
            if len(miss):
                Pi = np.repeat(P, m, axis=0)[miss]
                Mi = np.tile(M, (n, 1))[miss]
                cl, _ = via_cost(Pi, E, Mi, rm, task)
                flat = cost.ravel()
                flat[miss] = cl
                cost = flat.reshape(n, m)
            p = hit.mean(axis=1)
            return c0 + cost.mean(axis=1), {"c0": c0, "cu": cu, "p": p}

        return objective


def make_planner(name: str, core: PlanningCore, options: PlannerOptions | None = None, seed: int = 0) -> BasePlanner:
    if name == "field":
        from .field_planner import FieldPlanner  # the whole-field planner (issue 7), same factory

        return FieldPlanner(core, seed=seed)  # type: ignore[return-value]
    table = {"a": DeterministicPlanner, "b": DecoupledPlanner, "c": CapmPlanner, "cstar": BayesPlanner}
    if name not in table:
        raise UserError(f"unknown planner {name!r}; choose from {', '.join(table)}, field")
    return table[name](core, options, seed)
