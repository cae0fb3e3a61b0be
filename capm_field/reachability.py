"""Inverse reachability: R_o(TROI) and R_m(X) as sets of body poses relative to the target (paper §IV-B).

Method (FK sampling, see docs/model.md for resolution and measured error):
  * The Z1's first joint turns the whole arm about the vertical axis of the arm base, and the body
    keep-out cylinder and the ground are symmetric about that axis. So the maps are computed with
    joint 1 = 0 and a target's feasibility depends on its distance r from the arm axis and its
    bearing φ in the arm-base frame: feasible bearings at r are [φ_min(r) + q1_min, φ_max(r) + q1_max].
  * R_m (EPMC + pointing), by IK over a radial grid: a ground target at distance r is flameable
    if IK puts the flame axis (+x of the nozzle frame) through it at a distance t with
    t² ∈ [ε_min, ε_max] (‖X_e − X̄_w‖² ∈ [ε_min, ε_max], nozzle pointing at X̄_w) from a
    configuration whose arm clears body and ground and whose flame ray clears the body.
    (FK sampling hits this thin band too rarely to give clean boundaries.)
  * R_o (NSV): for each sampled camera pose the TROI disc is centred where the optical axis meets
    the ground; coverage (disc inside the image, in front of the camera, view rays clear the body)
    holds for r_w ≤ r_hi and target resolution h ≥ δ for r_w ≥ r_lo (both found by bisection on
    the exact conic projection in `camera.PinholeCamera.disc_view`).
  * A body pose x_b is in R_m(X) iff X, expressed in the arm-base frame of x_b, is in the map; the
    same for R_o(R_w^TROI) with the map of radius r_w.

Maps are cached on disk as .npz keyed by a hash of the robot config, the task thresholds and the
map resolution.
"""

from __future__ import annotations

import math
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from .camera import PinholeCamera
from .config import ReachabilityConfig, TaskConfig
from .errors import UserError
from .geometry import SE2, wrap_angle
from .robot_model import RobotModel

MAP_FORMAT = 4  # bump when the map semantics change: invalidates caches
TWO_PI = 2.0 * math.pi
_MIN_LOOK_DOWN = 0.2  # optical / flame axis must point at least this much downwards (−z component)


@dataclass(frozen=True)
class RadialSet:
    """A union of closed radial intervals [r_in, r_out] (m): the annulus summary of a region."""

    intervals: tuple[tuple[float, float], ...]

    @property
    def empty(self) -> bool:
        return not self.intervals

    @property
    def inner(self) -> float:
        return self.intervals[0][0] if self.intervals else math.nan

    @property
    def outer(self) -> float:
        return self.intervals[-1][1] if self.intervals else math.nan

    def contains(self, r: np.ndarray | float) -> np.ndarray:
        r = np.asarray(r, dtype=float)
        out = np.zeros(r.shape, dtype=bool)
        for a, b in self.intervals:
            out |= (r >= a) & (r <= b)
        return out

    def shrink(self, margin: float) -> "RadialSet":
        """The set with every interval shrunk by `margin` at both ends (planning stays clear of
        the map's bin edges); intervals that vanish are dropped."""
        return RadialSet(tuple((a + margin, b - margin) for a, b in self.intervals if b - a > 2 * margin))

    def intersect(self, other: "RadialSet") -> "RadialSet":
        out = []
        for a, b in self.intervals:
            for c, d in other.intervals:
                lo, hi = max(a, c), min(b, d)
                if hi > lo:
                    out.append((lo, hi))
        return RadialSet(tuple(sorted(out)))

    def clamp(self, r: float) -> float:
        """Nearest radius inside the set."""
        best, bd = math.nan, math.inf
        for a, b in self.intervals:
            c = min(max(r, a), b)
            if abs(c - r) < bd:
                best, bd = c, abs(c - r)
        return best


@dataclass(frozen=True)
class PolarMap:
    """Feasible target positions in the arm-base frame, indexed by distance from the arm axis.

    Bin k covers r ∈ [k·step, (k+1)·step). `lo[k]`, `hi[k]`: feasible bearings (rad, arm-base
    frame, joint-1 range included; NaN where no target at that distance is feasible). `full[k]`:
    every bearing is feasible. `seed_q[k]`: one configuration (joint 1 = 0) reaching a target at
    bearing `seed_phi[k]`, `seed_dist[k]` along its pointing axis — an IK seed.
    """

    step: float
    lo: np.ndarray
    hi: np.ndarray
    full: np.ndarray
    seed_q: np.ndarray
    seed_phi: np.ndarray
    seed_dist: np.ndarray

    def _bin(self, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        k = np.floor(np.asarray(r, dtype=float) / self.step).astype(int)
        ok = (k >= 0) & (k < len(self.lo))
        return np.where(ok, k, 0), ok

    def contains(self, r: np.ndarray | float, bearing: np.ndarray | float) -> np.ndarray:
        """Whether a target at distance r and bearing (arm-base frame) is feasible."""
        k, ok = self._bin(r)
        lo, hi = self.lo[k], self.hi[k]
        finite = ok & np.isfinite(lo)
        rel = np.mod(np.asarray(bearing, dtype=float) - np.where(finite, lo, 0.0), TWO_PI)
        return finite & (self.full[k] | (rel <= np.where(finite, hi - lo, 0.0)))

    def radial_set(self, bearing: float | None = None) -> RadialSet:
        """Radii feasible at `bearing` (None: at some bearing) as intervals — the annulus summary."""
        centres = (np.arange(len(self.lo)) + 0.5) * self.step
        mask = np.isfinite(self.lo) if bearing is None else self.contains(centres, np.full(len(centres), bearing))
        intervals = []
        k = 0
        n = len(mask)
        while k < n:
            if mask[k]:
                j = k
                while j + 1 < n and mask[j + 1]:
                    j += 1
                intervals.append((k * self.step, (j + 1) * self.step))
                k = j + 1
            else:
                k += 1
        return RadialSet(tuple(intervals))

    def annulus_by_bearing(self, n: int = 72) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(bearings, inner, outer): the annulus summary per bearing (NaN where empty)."""
        b = np.linspace(-math.pi, math.pi, n, endpoint=False)
        inner = np.full(n, np.nan)
        outer = np.full(n, np.nan)
        for i, bi in enumerate(b):
            s = self.radial_set(float(bi))
            if not s.empty:
                inner[i], outer[i] = s.inner, s.outer
        return b, inner, outer

    def seed_for(self, r: float, bearing: float) -> tuple[np.ndarray, float] | None:
        """IK seed (q with joint 1 turned to the bearing, pointing distance) for a target, or None."""
        k, ok = self._bin(np.array([r]))
        k = int(k[0])
        if not ok[0] or not np.isfinite(self.seed_phi[k]):
            return None
        q = self.seed_q[k].copy()
        q[0] = float(wrap_angle(bearing - self.seed_phi[k]))
        return q, float(self.seed_dist[k])


@dataclass(frozen=True)
class ReachabilityMaps:
    """R_m and R_o (one map per TROI radius) for one robot + task, plus build metadata."""

    manip: PolarMap
    observe: tuple[PolarMap, ...]
    troi_radii: np.ndarray  # r_w of each observe map
    key: str
    build_s: float
    samples: dict

    def bracketing_radii(self, r_w: float) -> tuple[float, ...]:
        """The mapped TROI radii just below and above r_w (one if r_w is on the grid)."""
        i = int(np.searchsorted(self.troi_radii, r_w - 1e-9))
        lo = self.troi_radii[max(i - 1, 0)] if self.troi_radii[min(i, len(self.troi_radii) - 1)] > r_w + 1e-9 else self.troi_radii[min(i, len(self.troi_radii) - 1)]
        hi = self.troi_radii[min(i, len(self.troi_radii) - 1)]
        return tuple(sorted({float(lo), float(hi)}))

    def observe_map(self, r_w: float) -> PolarMap:
        """The R_o map for TROI radius r_w (nearest built radius; r_w outside the range is an error)."""
        if not (self.troi_radii[0] - 1e-9 <= r_w <= self.troi_radii[-1] + 1e-9):
            raise ValueError(f"TROI radius {r_w} m outside the mapped range [{self.troi_radii[0]}, {self.troi_radii[-1]}]")
        return self.observe[int(np.argmin(np.abs(self.troi_radii - r_w)))]


# ---------------------------------------------------------------------------------------------
# Build
# ---------------------------------------------------------------------------------------------
def _joint_grid(robot: RobotModel, steps: tuple[int, ...], rolls: int) -> np.ndarray:
    lo, hi = robot.lower, robot.upper
    axes = [np.zeros(1)]
    for j, n in enumerate(steps, start=1):
        axes.append(np.linspace(lo[j], hi[j], n))
    axes.append(np.linspace(-math.pi, math.pi, rolls, endpoint=False) if rolls > 1 else np.zeros(1))
    axes[-1] = np.clip(axes[-1], lo[5], hi[5])
    grids = np.meshgrid(*axes, indexing="ij")
    return np.stack([g.ravel() for g in grids], axis=1)


def _collect(step: float, n_r: int, q1: tuple[float, float], r: np.ndarray, phi: np.ndarray, q: np.ndarray, dist: np.ndarray) -> PolarMap:
    """Group samples by radial bin into a PolarMap (bearing span + one IK seed per bin)."""
    lo = np.full(n_r, np.nan)
    hi = np.full(n_r, np.nan)
    seed_q = np.zeros((n_r, 6))
    seed_phi = np.full(n_r, np.nan)
    seed_dist = np.full(n_r, np.nan)
    k = np.floor(r / step).astype(int)
    keep = (k >= 0) & (k < n_r)
    k, phi, q, dist = k[keep], phi[keep], q[keep], dist[keep]
    if len(k):
        pmin = np.full(n_r, np.inf)
        pmax = np.full(n_r, -np.inf)
        np.minimum.at(pmin, k, phi)
        np.maximum.at(pmax, k, phi)
        has = np.isfinite(pmin)
        lo[has] = pmin[has] + q1[0]
        hi[has] = pmax[has] + q1[1]
        order = np.lexsort((np.abs(phi), k))  # per bin, the sample nearest straight ahead
        first = order[np.r_[True, k[order][1:] != k[order][:-1]]]
        seed_q[k[first]] = q[first]
        seed_phi[k[first]] = phi[first]
        seed_dist[k[first]] = dist[first]
    # Close holes of up to two bins left by sampling (feasible on both sides, empty between).
    for i in range(1, n_r - 1):
        if np.isnan(lo[i]) and np.isfinite(lo[i - 1]):
            j = next((j for j in (i + 1, i + 2) if j < n_r and np.isfinite(lo[j])), None)
            if j is not None:
                for m in range(i, j):
                    lo[m], hi[m] = max(lo[i - 1], lo[j]), min(hi[i - 1], hi[j])
                    seed_q[m], seed_phi[m], seed_dist[m] = seed_q[i - 1], seed_phi[i - 1], seed_dist[i - 1]
    full = np.isfinite(lo) & ((hi - lo) >= TWO_PI)
    return PolarMap(step, lo, hi, full, seed_q, seed_phi, seed_dist)


class FlameSolver:
    """IK for the manipulation key state x_e,k3: put the flame axis through a ground target X̄_w
    at a distance t with t² ∈ [ε_min, ε_max] (EPMC, nozzle pointing at X̄_w), from a valid pose.

    Seeds come from a coarse FK bank (joint 1 = 0, turned towards the target), so no caller
    needs a good initial guess. Validity: converged, flame axis within the tilt limit, arm clear
    of the body keep-out and the ground, flame ray not through the body.
    """

    def __init__(self, robot: RobotModel, task: TaskConfig, bank_steps: tuple[int, int, int, int] = (14, 14, 9, 5)):
        self.robot = robot
        self.t_lo, self.t_hi = math.sqrt(task.eps_min), math.sqrt(task.eps_max)
        Q = _joint_grid(robot, bank_steps, 1)
        fk = robot.fk_batch(Q)
        a = fk.nozzle[:, :3, 0]
        ok = (-a[:, 2] >= self.min_down) & ~robot.in_keepout(fk.points).any(axis=1)
        self.bank_q = Q[ok]
        t_mid = 0.5 * (self.t_lo + self.t_hi)
        self.bank_pts = fk.nozzle[ok, :3, 3] + t_mid * a[ok]

    @property
    def min_down(self) -> float:
        return max(math.cos(self.robot.cfg.nozzle.max_tilt), _MIN_LOOK_DOWN)

    def valid(self, q: np.ndarray, target_base: np.ndarray) -> bool:
        T = self.robot.frame_pose(q, RobotModel.NOZZLE)
        p, a = T[:3, 3], T[:3, 0]
        d = np.asarray(target_base) - p
        t = float(np.linalg.norm(d))
        if not (self.t_lo - 1e-6 <= t <= self.t_hi + 1e-6) or -a[2] < self.min_down - 1e-9:
            return False
        if float(np.dot(d / t, a)) < math.cos(0.01):  # pointing at the target within 10 mrad
            return False
        return self.robot.config_valid(q) and not bool(self.robot.segment_blocked(p, np.asarray(target_base)))

    def seeds(self, target_base: np.ndarray, n: int = 4) -> list[np.ndarray]:
        bearing = math.atan2(target_base[1], target_base[0])
        r = math.hypot(target_base[0], target_base[1])
        local = np.array([r, 0.0, target_base[2]])  # solve in the joint-1 = 0 plane, then turn
        d = np.linalg.norm(self.bank_pts - local, axis=1)
        out = []
        for i in np.argsort(d)[:n]:
            q = self.bank_q[i].copy()
            q[0] = bearing
            out.append(q)
        return out

    def solve(self, target_base: np.ndarray, extra_seeds: list[np.ndarray] | None = None) -> tuple[np.ndarray, float] | None:
        """(q, t) reaching the target, or None."""
        target_base = np.asarray(target_base, dtype=float)
        seeds = list(extra_seeds or []) + self.seeds(target_base)
        ts = (0.5 * (self.t_lo + self.t_hi), self.t_lo + 0.1 * (self.t_hi - self.t_lo), self.t_hi - 0.1 * (self.t_hi - self.t_lo))
        for t in ts:
            for q0 in seeds:
                q, conv, _ = self.robot.ik_axis_point(RobotModel.NOZZLE, target_base, t, q0, iters=60, tol=5e-4)
                if conv and self.valid(q, target_base):
                    return q, t
        return None


def _manip_map(robot: RobotModel, task: TaskConfig, rc: ReachabilityConfig, n_r: int) -> tuple[PolarMap, int]:
    """R_m by IK over a radial grid at bearing 0 (joint 1 provides the other bearings)."""
    solver = FlameSolver(robot, task)
    if len(solver.bank_pts) == 0:  # (was a numpy "zero-size array" error in the run's one error line)
        raise UserError(f"R_m is empty: no arm pose points the nozzle within robot.nozzle.max_tilt "
                        f"({math.degrees(robot.cfg.nozzle.max_tilt):.3g}°) of straight down clear of the body (check robot and task)")
    h = robot.height
    q1 = (float(robot.lower[0]), float(robot.upper[0]))
    rs, phis, qs, ts = [], [], [], []
    reach = float(np.max(np.hypot(solver.bank_pts[:, 0], solver.bank_pts[:, 1]))) + 0.15
    for k in range(n_r):
        r = (k + 0.5) * rc.radial_step
        if r > reach:
            break
        sol = solver.solve(np.array([r, 0.0, -h]))
        if sol is not None:
            q, t = sol
            rs.append(r)
            phis.append(-float(q[0]))  # bearing of the target with joint 1 at 0
            q = q.copy()
            q[0] = 0.0
            qs.append(q)
            ts.append(t)
    if not rs:
        return _collect(rc.radial_step, n_r, q1, np.zeros(0), np.zeros(0), np.zeros((0, 6)), np.zeros(0)), len(solver.bank_q)
    return _collect(rc.radial_step, n_r, q1, np.array(rs), np.array(phis), np.array(qs), np.array(ts)), len(solver.bank_q)


def _observe_samples(robot: RobotModel, task: TaskConfig, rc: ReachabilityConfig, chunk: int = 60_000):
    """Samples (r, φ, q, depth, r_lo, r_hi): camera poses and the TROI radii they see as NSV."""
    h = robot.height
    cam = PinholeCamera.from_config(robot.cfg.camera)
    Q = _joint_grid(robot, tuple(max(2, int(round(n * 0.75))) for n in rc.joint_steps), rc.roll_steps)
    r_max = rc.troi_radius_max
    out = []
    for i in range(0, len(Q), chunk):
        q = Q[i : i + chunk]
        fk = robot.fk_batch(q)
        T = fk.camera
        c = T[:, :3, 3]
        z = T[:, :3, 2]
        ok = (-z[:, 2] >= _MIN_LOOK_DOWN) & ~robot.in_keepout(fk.points).any(axis=1)
        q, T, c, z = q[ok], T[ok], c[ok], z[ok]
        depth = (-h - c[:, 2]) / z[:, 2]
        g = c + depth[:, None] * z  # TROI centre: optical axis ∩ ground (arm-base frame)
        Tg = T.copy()
        Tg[:, 2, 3] += h  # ground frame: z = 0 on the ground
        gxy = g[:, :2]

        def covered(r: np.ndarray) -> np.ndarray:
            cov, _ = cam.disc_view(Tg, gxy, r)
            return cov & ~robot.disc_occluded(c, g, r)

        def area(r: np.ndarray) -> np.ndarray:
            return cam.disc_view(Tg, gxy, r)[1]

        r_min_probe = np.full(len(q), rc.troi_radius_step)
        feasible = covered(r_min_probe)
        # r_hi: largest covered radius (coverage shrinks as the disc grows).
        lo_b, hi_b = r_min_probe.copy(), np.full(len(q), r_max)
        top = covered(hi_b)
        for _ in range(12):
            mid = 0.5 * (lo_b + hi_b)
            c_ok = covered(mid)
            lo_b = np.where(c_ok, mid, lo_b)
            hi_b = np.where(c_ok, hi_b, mid)
        r_hi = np.where(top, r_max, lo_b)
        # r_lo: smallest radius with h(x_e, R) ≥ δ (area grows with the radius).
        enough = area(r_hi) >= task.delta
        lo_b, hi_b = np.zeros(len(q)), r_hi.copy()
        for _ in range(12):
            mid = 0.5 * (lo_b + hi_b)
            a_ok = area(mid) >= task.delta
            hi_b = np.where(a_ok, mid, hi_b)
            lo_b = np.where(a_ok, lo_b, mid)
        r_lo = hi_b
        ok = feasible & enough & (r_lo <= r_hi)
        out.append((np.hypot(g[ok, 0], g[ok, 1]), np.arctan2(g[ok, 1], g[ok, 0]), q[ok], depth[ok], r_lo[ok], r_hi[ok]))
    return [np.concatenate(x) for x in zip(*out)] + [len(Q)]


def build_maps(
    robot: RobotModel, task: TaskConfig, rc: ReachabilityConfig, progress: Callable[[str], None] | None = None
) -> ReachabilityMaps:
    """Compute R_m and R_o maps from the arm kinematics (no cache)."""
    t0 = time.perf_counter()
    say = progress or (lambda _m: None)
    n_r = int(math.ceil(rc.radial_max / rc.radial_step))
    q1 = (float(robot.lower[0]), float(robot.upper[0]))
    say("R_m: IK over the radial grid")
    manip, n_manip = _manip_map(robot, task, rc, n_r)
    say("R_o: sampling camera poses")
    r, phi, q, depth, r_lo, r_hi, n_obs = _observe_samples(robot, task, rc)
    radii = np.round(np.arange(rc.troi_radius_step, rc.troi_radius_max + 1e-9, rc.troi_radius_step), 6)
    observe = []
    for rw in radii:
        sel = (r_lo <= rw) & (rw <= r_hi)
        observe.append(_collect(rc.radial_step, n_r, q1, r[sel], phi[sel], q[sel], depth[sel]))
    key = maps_key(robot, task, rc)
    return ReachabilityMaps(
        manip, tuple(observe), radii, key, time.perf_counter() - t0, {"nozzle_configs": n_manip, "camera_configs": n_obs}
    )


# ---------------------------------------------------------------------------------------------
# Cache
# ---------------------------------------------------------------------------------------------
def maps_key(robot: RobotModel, task: TaskConfig, rc: ReachabilityConfig) -> str:
    """The cache key of the maps: every value they depend on. The URDF by its contents, not its
    name: an edited URDF at the same path had its old maps read back (and a copy elsewhere, or a
    mission moved, rebuilt the same ones)."""
    import hashlib
    import json

    cfg = robot.cfg.model_dump(mode="json")
    cfg["arm"]["urdf"] = hashlib.sha256(Path(robot.urdf_path).read_bytes()).hexdigest()
    relevant = {
        "format": MAP_FORMAT,
        "robot": cfg,
        "task": {k: getattr(task, k) for k in ("delta", "eps_min", "eps_max")},
        "res": rc.model_dump(mode="json", exclude={"cache_dir"}),
    }
    return hashlib.sha256(json.dumps(relevant, sort_keys=True).encode()).hexdigest()[:16]


def cache_dir(rc: ReachabilityConfig) -> Path:
    if rc.cache_dir:
        return Path(os.path.expanduser(rc.cache_dir))
    env = os.environ.get("CAPM_FIELD_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "capm-field"


_FIELDS = ("lo", "hi", "full", "seed_q", "seed_phi", "seed_dist")


def save_maps(maps: ReachabilityMaps, path: Path) -> None:
    arrays = {f"manip_{f}": getattr(maps.manip, f) for f in _FIELDS}
    for f in _FIELDS:
        arrays[f"observe_{f}"] = np.stack([getattr(m, f) for m in maps.observe])
    arrays["troi_radii"] = maps.troi_radii
    arrays["meta"] = np.array([maps.manip.step, maps.build_s, maps.samples["nozzle_configs"], maps.samples["camera_configs"]])
    path.parent.mkdir(parents=True, exist_ok=True)
    # a name of this process's own: two processes building the same maps at once (a run and a
    # bench; tests side by side) wrote into one temporary file
    tmp = path.with_name(f"{path.stem}.{os.getpid()}.{threading.get_ident()}.tmp.npz")
    try:
        np.savez(tmp, **arrays)
        os.replace(tmp, path)  # atomic: a crash never leaves a half-written cache
    finally:
        tmp.unlink(missing_ok=True)


def load_maps(path: Path, key: str) -> ReachabilityMaps:
    with np.load(path) as z:
        step, build_s, n_m, n_o = (float(x) for x in z["meta"])
        manip = PolarMap(step, *(z[f"manip_{f}"] for f in _FIELDS))
        obs = tuple(PolarMap(step, *(z[f"observe_{f}"][i] for f in _FIELDS)) for i in range(len(z["troi_radii"])))
        return ReachabilityMaps(manip, obs, z["troi_radii"].copy(), key, build_s, {"nozzle_configs": int(n_m), "camera_configs": int(n_o)})


def get_maps(
    robot: RobotModel,
    task: TaskConfig,
    rc: ReachabilityConfig | None = None,
    progress: Callable[[str], None] | None = None,
    use_cache: bool = True,
) -> ReachabilityMaps:
    """Maps for this robot + task: from the on-disk cache when present, else built and cached."""
    rc = rc or ReachabilityConfig()
    key = maps_key(robot, task, rc)
    path = cache_dir(rc) / f"reach-{key}.npz"
    if use_cache and path.is_file():
        try:
            return load_maps(path, key)
        except Exception:  # noqa: BLE001 - a corrupt cache is rebuilt, never fatal
            pass
    maps = build_maps(robot, task, rc, progress)
    if use_cache:
        try:
            save_maps(maps, path)
        except OSError:
            pass  # read-only home: run without a cache
    return maps


# ---------------------------------------------------------------------------------------------
# Regions in the field frame
# ---------------------------------------------------------------------------------------------
class Regions:
    """R_o and R_m as predicates on body poses, and their annulus summaries, for one robot + task."""

    def __init__(self, robot: RobotModel, maps: ReachabilityMaps):
        self.robot = robot
        self.maps = maps

    def target_polar(self, body: SE2, target_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Target(s) in the arm-base frame of `body`: (distance from the arm axis, bearing)."""
        T = self.robot.T_field_base(body)
        d = np.asarray(target_xy, dtype=float) - T[:2, 3]
        c, s = T[0, 0], T[1, 0]  # arm-base x axis in the field
        lx = c * d[..., 0] + s * d[..., 1]
        ly = -s * d[..., 0] + c * d[..., 1]
        return np.hypot(lx, ly), np.arctan2(ly, lx)

    def in_R_m(self, body: SE2, mpoi_xy: np.ndarray) -> np.ndarray:
        """x_b ∈ R_m(X̄_w): some nozzle pose from x_b satisfies EPMC for the MPOI (and MTC by holding it)."""
        return self.maps.manip.contains(*self.target_polar(body, mpoi_xy))

    def in_R_o(self, body: SE2, troi_xy: np.ndarray, r_w: float) -> np.ndarray:
        """x_b ∈ R_o(R_w^TROI): some camera pose from x_b satisfies NSV for the TROI."""
        return self.maps.observe_map(r_w).contains(*self.target_polar(body, troi_xy))

    def R_m_radial(self, bearing: float | None = 0.0) -> RadialSet:
        return self.maps.manip.radial_set(bearing)

    def R_o_radial(self, r_w: float, bearing: float | None = 0.0) -> RadialSet:
        return self.maps.observe_map(r_w).radial_set(bearing)


def problem_type(ro: RadialSet, rm: RadialSet, mpoi_offset: float = 0.0, r_w: float | None = None) -> str:
    """The paper's CAPM problem type (§IV-C) from the annulus summaries of R_o and R_m.

    I: R_m lies inside R_o's inner hole (disjoint); II: they overlap and neither contains the other;
    III: R_o lies inside R_m's inner hole; IV: the MPOI is outside the TROI and the regions are
    disjoint. Nested overlaps (one contains the other) are reported as 'II-nested'.
    `mpoi_offset` shifts R_m's centre by that distance from X_w (worst case over directions).
    """
    if ro.empty or rm.empty:
        return "none"
    o_in, o_out, m_in, m_out = ro.inner, ro.outer, rm.inner, rm.outer
    # With centres `mpoi_offset` apart, the annuli can intersect iff radii ranges overlap within it.
    disjoint = (m_out + mpoi_offset < o_in) or (o_out + mpoi_offset < m_in) or (mpoi_offset > o_out + m_out)
    if r_w is not None and mpoi_offset > r_w and disjoint:
        return "IV"
    if m_out + mpoi_offset < o_in:
        return "I"
    if o_out + mpoi_offset < m_in:
        return "III"
    if (o_in <= m_in and m_out <= o_out) or (m_in <= o_in and o_out <= m_out):
        return "II-nested"
    return "II"
