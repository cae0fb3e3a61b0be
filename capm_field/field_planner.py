"""Field planner: CAPM across targets (project issue 7).

The paper plans one TROI at a time: S → x_b,k1 → (x_b,k3) → x_kmax, x_kmax the midpoint
towards the next TROI. Per target that is near-optimal; across targets three things are lost,
and this planner wins them back:

  (i)   no separate walk to x_kmax: the flaming pose of target i *is* the start of target i+1
        (x_kmax = the flame pose), chosen for the next target's benefit;
  (ii)  the flame pose (x_b,k1 on the upper branch, x_b,k3 on the lower) is chosen so that,
        where possible, it is already in R_o of the next TROI (observe it without walking) or in
        R_m of its MPOI when that is known (flame it without walking);
  (iii) an observation stop x_b,k1 whose one camera pose sees several TROIs with NSV (checked
        with `PinholeCamera.disc_view` on actual arm poses, view_bank.py): every TROI seen gets
        its MPOI X̄_w, and a target whose MPOI is known is planned like the oracle — a single
        flaming stop in R_m(X̄_w), no observation.

Stop choice (one target ahead, vectorised over a polar grid of candidate positions):
  known X̄_i:   x_b ∈ R_m(X̄_i) minimising c(x, x_b) + T(x_b) − κ·#(other known targets flamed from x_b)
  unknown:     x_b,k1 ∈ R_o(X_i) minimising
               c(x, x_b,k1) + E_X̄i[ 1[x_b,k1 ∈ R_m(X̄_i)]·T(x_b,k1)
                                   + 1[x_b,k1 ∉ R_m(X̄_i)]·(1 + γ·D(x_b,k1, R_m(X̄_i)) + T(proj)) ] − b·#revealed
  after X̄_i:   x_b,k3 ∈ R_m(X̄_i) ∪ {x_b,k1 if it is in R_m(X̄_i)} minimising c(x_b,k1, x_b,k3) + T(x_b,k3)
T(x) is the cost-to-go of the next target from x: known MPOI → 0 inside R_m(X̄_j), else one move
plus γ·distance to it; unknown → E over its prior of the reposition after observing from x
(plus the walk into R_o(X_j) when x is outside it); the user's end pose after the last target.
E over the MPOI prior N(X_w, Σ_w) (optionally restricted to the TROI) is a fixed scrambled-Sobol
quadrature, so plans are deterministic. The visiting order is NN + 2-opt on the best-known
points (X̄_w where known, X_w otherwise) and is re-optimised after every observation; targets
that can be flamed from where the robot stands are taken first.

The oracle (`OraclePlanner`) is the same machinery told every MPOI at the start: no
observation stops, one stop per weed or one stop for several weeds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import energy
from .geometry import SE2
from .keystates import TROI, KeyState, Outcome, Plan
from .planners import PlanningCore
from .field_order import order_points
from .reachability import RadialSet
from .view_bank import ViewBank

_BANKS: dict[int, ViewBank] = {}


def view_bank(core: PlanningCore) -> ViewBank:
    """One ViewBank per robot model in this process (≈ 0.2 s to build)."""
    key = id(core.robot)
    if key not in _BANKS:
        _BANKS[key] = ViewBank(core.robot, core.task)
    return _BANKS[key]


@dataclass(frozen=True)
class FieldOptions:
    n_radii: int = 7  # candidate stops: polar grid over the annulus (radii × angles)
    n_angles: int = 36
    n_quad: int = 16  # Sobol points of the MPOI prior (the current target)
    n_quad_inner: int = 8  # … of the next target's prior inside the cost-to-go (a balanced Sobol prefix)
    in_troi: bool = False  # prior restricted to the TROI disc (truncated Rayleigh radius)
    reveal_bonus: float = 0.4  # value of learning one more MPOI in a view (≈ saved reposition)
    cover_bonus: float = 1.0  # value of flaming one more known target from the same stop (one move)
    group_radius: float = 1.0  # unknown TROIs within this of X_i are candidates for a shared view
    group_verify: int = 2  # bank checks per re-plan (best candidates first)
    view_neighbours: int = 8  # at most this many of them (nearest in visiting order)
    proxy_drho: float = 0.25  # shared-view proxy: |ρ_j − ρ_i| from the stop (m) …
    proxy_dbearing: float = 0.6  # … and bearing difference (rad), both from the bank's feasible set
    oracle: bool = False


def _ring(X: np.ndarray, rs: RadialSet, n_r: int, n_a: int, phase: float = 0.0) -> np.ndarray:
    """Candidate positions on a polar grid over the annulus rs around X (n, 2)."""
    out = []
    a = phase + np.linspace(-math.pi, math.pi, n_a, endpoint=False)
    for lo, hi in rs.intervals:
        r = np.linspace(lo, hi, n_r)
        R, A = np.meshgrid(r, a, indexing="ij")
        out.append(np.stack([X[0] + R.ravel() * np.cos(A.ravel()), X[1] + R.ravel() * np.sin(A.ravel())], 1))
    return np.concatenate(out) if out else np.zeros((0, 2))


def _ann_dist(P: np.ndarray, C: np.ndarray, rs: RadialSet) -> tuple[np.ndarray, np.ndarray]:
    """(distance from P to the annulus rs around C, nearest annulus point), broadcast over P and C."""
    d = P - C
    dx, dy = d[..., 0], d[..., 1]
    r = np.sqrt(dx * dx + dy * dy)
    if len(rs.intervals) == 1:  # the common case: one interval, no per-interval selection
        lo, hi = rs.intervals[0]
        rc = np.clip(r, lo, hi)
        best = np.abs(r - rc)
    else:
        best = np.full(r.shape, np.inf)
        rc = np.zeros(r.shape)
        for lo, hi in rs.intervals:
            c = np.clip(r, lo, hi)
            dd = np.abs(r - c)
            better = dd < best
            best = np.where(better, dd, best)
            rc = np.where(better, c, rc)
    s = rc / np.maximum(r, 1e-12)  # P on the centre: any direction will do (x axis)
    qx = np.where(r > 1e-12, dx * s, rc)
    qy = dy * s
    C = np.broadcast_to(C, d.shape)
    return best, np.stack([C[..., 0] + qx, C[..., 1] + qy], axis=-1)


def _ann_gap(P: np.ndarray, C: np.ndarray, rs: RadialSet) -> np.ndarray:
    """Distance from P to the annulus rs around C only (the cheap half of `_ann_dist`)."""
    d = P - C
    r = np.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2)
    if len(rs.intervals) == 1:
        lo, hi = rs.intervals[0]
        return np.maximum(np.maximum(lo - r, r - hi), 0.0)
    return np.min([np.maximum(np.maximum(lo - r, r - hi), 0.0) for lo, hi in rs.intervals], axis=0)


class FieldPlanner:
    """Plans a whole field: visiting order, shared key states, multi-TROI views; re-plans online.

    Call order per target (the executive's, and `field_sim`'s):
      plan = next_plan(here, known)          → None when every target is done
      walk to x_b,k1; if plan observes (has x_e,k2): capture, detect the MPOI of the target
        and of every id in plan.terms["also_observe"] → observed(id, mpoi, also_seen)
      out = after_observation(plan, mpoi)    → the executed key states (x_kmax = flame pose)
      flame; done(id, flamed)
    """

    name = "field"

    def __init__(self, core: PlanningCore, options: FieldOptions | None = None, seed: int = 0):
        self.core = core
        self.task = core.task
        self.opt = options or FieldOptions()
        self.seed = seed
        self.bank = view_bank(core)
        from scipy.stats import qmc

        u = qmc.Sobol(d=2, scramble=True, seed=4321).random(self.opt.n_quad)
        self._u = np.clip(u, 1e-6, 1 - 1e-6)
        self.trois: dict[str, TROI] = {}
        self.order: list[str] = []
        self.known: dict[str, tuple[float, float]] = {}
        self.start_pose: SE2 | None = None
        self.end_pose: SE2 | None = None
        self._quad: dict[str, np.ndarray] = {}
        self._last_here: SE2 | None = None

    # ---- state -----------------------------------------------------------------------------
    def start(self, trois: list[TROI], start: SE2, end: SE2) -> list[TROI]:
        """Initial visiting order (NN + 2-opt over X_w, or X̄_w when already known)."""
        ids = [t.id or str(i) for i, t in enumerate(trois)]
        if len(set(ids)) != len(ids):
            raise ValueError("TROI ids must be unique")
        self.trois = {i: (t if t.id else TROI(t.x, t.y, t.r, i)) for i, t in zip(ids, trois)}
        self.order = list(ids)
        self.start_pose, self.end_pose = start, end
        self._last_here = start
        self._quad = {}
        self._reorder(start.xy)
        return [self.trois[i] for i in self.order]

    def observed(self, troi_id: str, mpoi_xy: tuple[float, float] | None, also_seen: dict[str, tuple[float, float]] | None = None) -> None:
        """Record detected MPOIs (the target's and any seen in the same image); re-plan the order."""
        new = False
        if mpoi_xy is not None:
            new |= troi_id not in self.known
            self.known[troi_id] = (float(mpoi_xy[0]), float(mpoi_xy[1]))
        for k, v in (also_seen or {}).items():
            if k in self.trois and k not in self.known:
                self.known[k] = (float(v[0]), float(v[1]))
                new = True
        if new and self._last_here is not None:
            rest = [i for i in self.order if i != troi_id]
            head = [troi_id] if troi_id in self.order else []
            self.order = head + self._order_from(rest, self._last_here.xy)

    def done(self, troi_id: str, flamed: bool) -> None:
        """The target is finished (flamed or skipped): drop it from the order."""
        if troi_id in self.order:
            self.order.remove(troi_id)

    # ---- geometry helpers ------------------------------------------------------------------
    def _point(self, tid: str) -> np.ndarray:
        return np.array(self.known[tid] if tid in self.known else self.trois[tid].xy)

    def _order_from(self, ids: list[str], here_xy: np.ndarray) -> list[str]:
        if not ids:
            return []
        pts = np.array([self._point(i) for i in ids])
        idx = order_points(pts, here_xy, self.end_pose.xy if self.end_pose is not None else None)
        return [ids[k] for k in idx]

    def _reorder(self, here_xy: np.ndarray) -> None:
        self.order = self._order_from(self.order, here_xy)

    def _quadrature(self, tid: str) -> tuple[np.ndarray, float]:
        """MPOI prior quadrature points of a TROI (polar: Rayleigh radius, uniform angle)."""
        t = self.trois[tid]
        sigma = self.task.sigma(t.r)
        if tid not in self._quad:
            q = self._u[:, 0]
            if self.opt.in_troi:
                q = q * (1.0 - math.exp(-(t.r**2) / (2 * sigma**2)))
            rad = sigma * np.sqrt(-2.0 * np.log1p(-q))
            ang = 2 * math.pi * self._u[:, 1]
            self._quad[tid] = np.array(t.xy) + np.stack([rad * np.cos(ang), rad * np.sin(ang)], 1)
        return self._quad[tid], sigma

    def _move(self, A: np.ndarray, B: np.ndarray) -> np.ndarray:
        """c(A, B) for positions (…, 2): one move plus γ·d, zero when B = A."""
        d = energy.travel(B - A, self.task)
        return np.where(d > 1e-9, 1.0 + self.task.gamma * d, 0.0)

    def _reach_known(self, P: np.ndarray, M: np.ndarray) -> np.ndarray:
        """Cost to a flame stop for a known MPOI M from P: 0 inside R_m(M), else one move + γ·distance."""
        d = _ann_gap(P, M, self.core.rm)
        return np.where(d <= 1e-9, 0.0, 1.0 + self.task.gamma * d)

    def _miss_cost(self, P: np.ndarray, tid: str) -> np.ndarray:
        """E over the prior of tid's MPOI of the reposition after observing from P: P (…, 2) → (…).
        Used inside the cost-to-go, so on the smaller inner quadrature."""
        Mq, _ = self._quadrature(tid)
        return self._reach_known(P[..., None, :], Mq[: self.opt.n_quad_inner]).mean(axis=-1)

    def _cost_to_go(self, P: np.ndarray, nxt: str | None, revealed: set[str] = frozenset()) -> np.ndarray:  # type: ignore[assignment]
        """T(P): cost-to-go of the next target (or the end pose) from a flame pose P."""
        if nxt is None:
            assert self.end_pose is not None
            return self._move(P, self.end_pose.xy)
        if nxt in self.known:
            return self._reach_known(P, np.array(self.known[nxt]))
        if nxt in revealed:  # known after this view: expected reach cost over its prior
            return self._miss_cost(P, nxt)
        t = self.trois[nxt]
        ro = self.core.ro(t.r)
        d, Q = _ann_dist(P, np.array(t.xy), ro)
        inside = d <= 1e-9
        return np.where(inside, self._miss_cost(P, nxt), 1.0 + self.task.gamma * d + self._miss_cost(Q, nxt))

    def _covered_bonus(self, P: np.ndarray, skip: set[str]) -> np.ndarray:
        """κ · number of other known, remaining targets whose MPOI is in R_m from P."""
        others = [i for i in self.order if i in self.known and i not in skip]
        if not others:
            return np.zeros(len(P))
        M = np.array([self.known[i] for i in others])
        r = np.linalg.norm(P[:, None, :] - M[None], axis=2)
        return self.opt.cover_bonus * self.core.rm.contains(r).sum(axis=1)

    def _yaw_for(self, P: np.ndarray, flame: np.ndarray | None, look: np.ndarray | None) -> float:
        """Body yaw at P: face the flame target, turned towards the next view target when the flame
        target stays inside R_m's bearing span (joint 1 covers ±150°)."""
        tgt = flame if flame is not None else look
        assert tgt is not None
        y0 = math.atan2(tgt[1] - P[1], tgt[0] - P[0])
        if flame is None or look is None:
            return y0
        y1 = math.atan2(look[1] - P[1], look[0] - P[0])
        mid = y0 + 0.5 * math.atan2(math.sin(y1 - y0), math.cos(y1 - y0))
        body = self.core.robot.body_for_arm_base(P, mid)
        return mid if bool(self.core.regions.in_R_m(body, flame)) else y0

    def _body(self, P: np.ndarray, yaw: float) -> SE2:
        return self.core.robot.body_for_arm_base(P, yaw)

    # ---- planning --------------------------------------------------------------------------
    def _free_first(self, here: np.ndarray) -> None:
        """Targets whose known MPOI is in R_m from where the robot stands go first (no walk)."""
        free = [i for i in self.order if i in self.known and self.core.rm.contains(np.linalg.norm(np.array(self.known[i]) - here))]
        if free:
            self.order = free + [i for i in self.order if i not in free]

    def next_plan(self, here: SE2, known: dict[str, tuple[float, float]] | None = None) -> Plan | None:
        """Plan for the next target from `here`; Plan.end = x_kmax = where this target's work ends."""
        for k, v in (known or {}).items():
            if k in self.trois:
                self.known[k] = (float(v[0]), float(v[1]))
        self._last_here = here
        if not self.order:
            return None
        H = self.core.base_xy(here)
        self._free_first(H)
        tid = self.order[0]
        nxt = self.order[1] if len(self.order) > 1 else None
        if tid in self.known:
            return self._plan_known(here, H, tid, nxt)
        return self._plan_unknown(here, H, tid, nxt)

    def _flame_stop(self, start: np.ndarray, tid: str, M: np.ndarray, nxt: str | None, forced: bool, extra: np.ndarray | None = None) -> tuple[np.ndarray, float, dict]:
        """argmin over x_b ∈ R_m(M) (plus `extra` candidates inside it) of c(start, x_b) + T(x_b) − κ·covered."""
        C = _ring(M, self.core.rm, self.opt.n_radii, self.opt.n_angles)
        if extra is not None:
            C = np.vstack([extra, C])
        move = self._move(start, C)
        if forced:  # the reposition x_b,k1 → x_b,k3 always counts as a move
            move = np.where(np.linalg.norm(C - start, axis=1) > 1e-9, move, 1.0)
        T = self._cost_to_go(C, nxt)
        J = move + T - self._covered_bonus(C, {tid} | ({nxt} if nxt else set()))
        k = int(np.argmin(J))
        return C[k], float(J[k]), {"c_move": float(move[k]), "cost_to_go": float(T[k])}

    def _end_or_here(self, nxt: str | None, body: SE2) -> SE2:
        return body

    def _look_point(self, nxt: str | None) -> np.ndarray | None:
        if nxt is None:
            return None
        return self._point(nxt)

    def _plan_known(self, here: SE2, H: np.ndarray, tid: str, nxt: str | None) -> Plan:
        """Oracle-style: one flaming stop in R_m(X̄_w), no observation: [x_k0, x_b,k1, x_e,k3, x_kmax]."""
        troi = self.trois[tid]
        M = np.array(self.known[tid])
        inside = self.core.rm.contains(np.linalg.norm(H - M))
        P, J, terms = self._flame_stop(H, tid, M, nxt, False, H[None] if inside else None)
        if np.linalg.norm(P - H) <= 1e-9:
            body = here if bool(self.core.regions.in_R_m(here, M)) else self._body(H, self._yaw_for(H, M, None))
        else:
            body = self._body(P, self._yaw_for(P, M, self._look_point(nxt)))
        end = self.end_pose if nxt is None else body
        ks = (KeyState("x_k0", here), KeyState("x_b,k1", body), KeyState("x_e,k3", body, "flame", tuple(M)), KeyState("x_kmax", end))
        terms.update({"known": True, "also_observe": [], "objective": J})
        return Plan(self.name, troi, here, end, ks, 1.0, float(self._move(H, P)) + terms["cost_to_go"], None, terms)

    def _unknown_objective(self, H: np.ndarray, tid: str, C: np.ndarray, nxt: str | None, revealed: set[str]) -> tuple[np.ndarray, np.ndarray]:
        """(J, p) of observation stops C for unknown target tid (see the module docstring)."""
        Mq, _ = self._quadrature(tid)
        g = self.task.gamma
        d, Q = _ann_dist(C[:, None, :], Mq[None], self.core.rm)  # (n, q)
        hit = d <= 1e-9
        p = hit.mean(axis=1)
        T_here = self._cost_to_go(C, nxt, revealed)
        T_miss = self._cost_to_go(Q.reshape(-1, 2), nxt, revealed).reshape(Q.shape[:2])
        exp = np.where(hit, T_here[:, None], 1.0 + g * d + T_miss).mean(axis=1)
        return self._move(H, C) + exp, p

    def _reveal_proxy(self, C: np.ndarray, tid: str, near: list[str]) -> np.ndarray:
        """Predicted co-visible unknown TROIs per candidate stop (n, k) bool: in R_o radially, at
        about the primary's distance and within the camera's horizontal field of view of it
        (side by side in the image, the arrangement the bank finds feasible). Verified by the bank."""
        if not near:
            return np.zeros((len(C), 0), bool)
        X = np.array(self.trois[tid].xy)
        U = np.array([self.trois[j].xy for j in near])
        d = C[:, None, :] - U[None]
        rho = np.hypot(d[..., 0], d[..., 1])
        rho_i = np.linalg.norm(C - X, axis=1)
        b = np.arctan2(-d[..., 1], -d[..., 0])
        b_i = np.arctan2(X[1] - C[:, 1], X[0] - C[:, 0])
        db = np.abs(np.angle(np.exp(1j * (b - b_i[:, None]))))
        ok = (np.abs(rho - rho_i[:, None]) <= self.opt.proxy_drho) & (db <= self.opt.proxy_dbearing)
        for k, j in enumerate(near):
            ok[:, k] &= self.core.ro(self.trois[j].r).contains(rho[:, k])
        return ok

    def _plan_unknown(self, here: SE2, H: np.ndarray, tid: str, nxt: str | None) -> Plan:
        troi = self.trois[tid]
        X = np.array(troi.xy)
        r_eff = self.core.effective_radius(troi.r)
        ro = self.core.ro(troi.r)
        C = _ring(X, ro, self.opt.n_radii, self.opt.n_angles)
        here_in = bool(ro.contains(np.linalg.norm(H - X)))
        if here_in:
            C = np.vstack([H[None], C])
        J, p = self._unknown_objective(H, tid, C, nxt, set())
        # (iii) shared views: other unknown TROIs the same image may show (proxy, then the bank).
        near = [j for j in self.order[1:] if j not in self.known and np.linalg.norm(np.array(self.trois[j].xy) - X) <= self.opt.group_radius]
        near = near[: self.opt.view_neighbours]
        co = self._reveal_proxy(C, tid, near)
        Jp = J - self.opt.reveal_bonus * co.sum(axis=1)
        order = np.argsort(Jp, kind="stable")
        best = None
        for n_check, k in enumerate(order[: self.opt.group_verify]):
            group = tuple(j for j, c in zip(near, co[k]) if c)
            view = self._view(C[k], tid, group, near)
            if view is None:
                continue
            body, gv, seen_ids = view
            val = float(J[k] - self.opt.reveal_bonus * (len(seen_ids) - 1))
            if best is None or val < best[0]:
                best = (val, C[k], float(p[k]), body, gv, seen_ids)
            if len(seen_ids) - 1 >= len(group):
                break  # as good as predicted: no later candidate can beat it under the proxy
        if best is None:  # no bank pose verified: the best single-view stop of the R_o map
            k = int(np.argmin(J))
            best = (float(J[k]), C[k], float(p[k]), self._body(C[k], math.atan2(X[1] - C[k][1], X[0] - C[k][0])), None, [tid])
        val, P1, pk, body, gv, seen_ids = best
        if np.linalg.norm(P1 - H) <= 1e-9 and abs(body.yaw - here.yaw) < 1e-9:
            body = here
        P3, _, _ = self._flame_stop(P1, tid, X, nxt, True)
        x3 = self._body(P3, math.atan2(X[1] - P3[1], X[0] - P3[0]))
        ks = (
            KeyState("x_k0", here),
            KeyState("x_b,k1", body),
            KeyState("x_e,k2", body, "observe", troi.xy, r_eff),
            KeyState("x_e,k3", body, "flame", troi.xy),
            KeyState("x_kmax", body if nxt is not None else self.end_pose),
        )
        terms = {
            "known": False,
            "also_observe": [s for s in seen_ids if s != tid],
            "objective": val,
            "r_eff": r_eff,
            "p": pk,
            "view_q": None if gv is None else [float(x) for x in gv.q],
            "view_T": None if gv is None else gv.T_field_cam,
        }
        end = body if nxt is not None else self.end_pose
        assert end is not None
        return Plan(self.name, troi, here, end, ks, pk, val, x3, terms)

    def _view(self, P1: np.ndarray, tid: str, group: tuple[str, ...], near: list[str]) -> tuple[SE2, object, list[str]] | None:
        """A bank camera pose from arm base P1 that sees tid with NSV and as many of `group` as it
        can; then every TROI of `near` the same image shows with NSV (those reveal for free)."""
        X = np.array(self.trois[tid].xy)
        aim = np.mean([X] + [np.array(self.trois[g].xy) for g in group], axis=0)
        body = self._body(P1, math.atan2(aim[1] - P1[1], aim[0] - P1[0]))
        ids = [tid, *group]
        gv = self.bank.best_view(body, np.array([self.trois[i].xy for i in ids]), np.array([self.core.effective_radius(self.trois[i].r) for i in ids]))
        if gv is None or not bool(gv.seen[0]):
            return None
        seen = [i for i, s in zip(ids, gv.seen) if s]
        rest = [i for i in near if i not in ids]
        if rest:
            extra = self.bank.seen_from(gv.T_field_cam, body, np.array([self.trois[i].xy for i in rest]), np.array([self.core.effective_radius(self.trois[i].r) for i in rest]))
            seen += [i for i, s in zip(rest, extra) if s]
        return body, gv, seen

    # ---- after observation -----------------------------------------------------------------
    def _replan_k3(self, P1: np.ndarray, E: np.ndarray, mpoi: np.ndarray) -> np.ndarray:
        """x_b,k3 ∈ R_m(X̄_w) for the current target with the field's cost-to-go (E is ignored:
        the next target, not a fixed x_kmax, decides). Same signature as the per-target planners."""
        tid = self.order[0] if self.order else None
        nxt = self.order[1] if len(self.order) > 1 else None
        P3, _, _ = self._flame_stop(np.asarray(P1, float), tid or "", np.asarray(mpoi, float), nxt, True)
        return P3

    def after_observation(self, plan: Plan, mpoi_xy) -> Outcome:
        """Branch once X̄_w is known: stay and flame at x_b,k1 (upper) or reposition to the x_b,k3 ∈
        R_m(X̄_w) that is best for the next target (lower). x_kmax = the flame pose."""
        mpoi = np.asarray(mpoi_xy, dtype=float)
        tid = plan.troi.id
        if tid and tid not in self.known:
            self.known[tid] = (float(mpoi[0]), float(mpoi[1]))
        x1 = plan.x_b_k1
        observes = plan.state("x_e,k2") is not None
        rest = [i for i in self.order if i != tid]
        nxt = rest[0] if rest else None
        last = nxt is None
        if not observes:
            body = x1
            seq = [plan.state("x_k0"), plan.state("x_b,k1"), KeyState("x_e,k3", body, "flame", tuple(mpoi))]
            bodies, forced, branch = [plan.start, body], set(), "upper"
        else:
            P1 = self.core.base_xy(x1)
            in1 = bool(self.core.rm.contains(np.linalg.norm(P1 - mpoi))) and bool(self.core.regions.in_R_m(x1, mpoi))
            P3, _, _ = self._flame_stop(P1, tid, mpoi, nxt, True, P1[None] if in1 else None)
            seq = [plan.state("x_k0"), plan.state("x_b,k1"), plan.state("x_e,k2")]
            if np.linalg.norm(P3 - P1) <= 1e-9:
                body = x1
                seq.append(KeyState("x_e,k3", body, "flame", tuple(mpoi)))
                bodies, forced, branch = [plan.start, x1], set(), "upper"
            else:
                body = self._body(P3, self._yaw_for(P3, mpoi, self._look_point(nxt)))
                seq += [KeyState("x_b,k3", body), KeyState("x_e,k3", body, "flame", tuple(mpoi))]
                bodies, forced, branch = [plan.start, x1, body], {2}, "lower"
        end = self.end_pose if last else body
        assert end is not None
        seq.append(KeyState("x_kmax", end))
        if last:
            bodies = bodies + [end]
        cost = energy.path_cost(bodies, self.task, forced)
        moves = sum(1 for i in range(len(bodies) - 1) if (i + 1) in forced or bodies[i].distance(bodies[i + 1]) > 1e-9)
        ok = bool(self.core.regions.in_R_m(body, mpoi))
        return Outcome(self.name, branch, tuple(k for k in seq if k is not None), cost, moves, ok)  # type: ignore[arg-type]


class OraclePlanner(FieldPlanner):
    """Known-MPOI reference: told every X̄_w at the start, so every target is a single flaming stop
    in R_m(X̄_w) (several targets share a stop when it is in R_m of each); no observation stop.
    Same order and stop optimiser as the field planner — a heuristic, not a proven lower bound."""

    name = "oracle"

    def __init__(self, core: PlanningCore, options: FieldOptions | None = None, seed: int = 0, truth: dict[str, tuple[float, float]] | None = None):
        super().__init__(core, options, seed)
        self._truth = dict(truth or {})

    def start(self, trois: list[TROI], start: SE2, end: SE2) -> list[TROI]:
        self.known = {k: (float(v[0]), float(v[1])) for k, v in self._truth.items()}
        return super().start(trois, start, end)
