"""Mission executive: walks the key-state sequence of every TROI on any DriverSet (bench or robot).

Per TROI (paper §III-B, Fig. 2c): plan → walk to x_b,k1 → arm to the NSV pose x_e,k2 → capture →
detect the MPOI → branch (upper: flame from x_b,k1; lower: re-plan x_b,k3 ∈ R_m(X̄_w) and walk) →
flame with the MTC hold ξ under the ignition interlock → stow → walk to x_kmax.

Recovery: detection fails (no answer, or any reason: "ambiguous" included, whose best-guess
pixel is logged but never flamed) → one re-observation from an adjusted pose, then skip with a reason;
CAMERA_FAULT_FRAMES frames in a row without a usable image (none arrived, or "bad_image") → abort: the
camera is at fault, and walking on would skip every weed left;
IK or motion failure → re-plan once, then skip; link loss or E-stop → igniter off, stow if
possible, abort (MissionAborted → exit 1). The arm is stowed before every body move
(assumption a.2: body and arm never move together), and the igniter is extinguished before
anything that is not flaming.
"""

from __future__ import annotations

import time
import traceback
from dataclasses import asdict, dataclass, field
from typing import Callable

import numpy as np

from capm_field import energy
from capm_field.arm_poses import ArmSolution, ViewSolver, flame_solution
from capm_field.camera import PinholeCamera
from capm_field.detector import detect_centre, roi_from_troi
from capm_field.geometry import SE2, wrap_angle
from capm_field.keystates import TROI, KeyState, Plan
from capm_field.planners import BasePlanner, PlanningCore
from capm_field.reachability import FlameSolver
from drivers.interfaces import DriverError, DriverSet, DriverTimeout, EStopActive, LinkLost

from .config import FUEL_RESERVE, hold_fuel, holds_left
from .interlock import IgnitionInterlock
from .interrupts import HeldSignals
from .ordering import order_trois
from .ordering import x_kmax as x_kmax_of


TF_PERIOD_NS = 100_000_000  # /tf while the body or the arm moves: at most every 0.1 s of the run's clock
CAMERA_FAULT_FRAMES = 4  # frames in a row without a usable image (capture timed out, or the detector said
# "bad_image": black, over-exposed, no colour, noise) after which the mission aborts: two targets' worth of
# observations (each has two attempts), so a single dropped or black frame only costs a re-observation
ROI_MARGIN = 1.5  # × r_w: the MPOI lies in the TROI by design; the margin keeps plants whose centre sits on the rim


def roi_for(camera, T_cam: np.ndarray, xy, r: float):
    """The ROI the detector searches for a TROI (centre xy, radius r) seen from T_cam: the TROI
    grown by ROI_MARGIN (`capm-field detect-replay` rebuilds it from a run log the same way)."""
    return roi_from_troi(camera, T_cam, xy, ROI_MARGIN * r)


class MissionAborted(RuntimeError):
    """Link loss, E-stop or another condition under which the mission must not go on."""


class _Skip(Exception):
    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


@dataclass
class TargetResult:
    id: str
    troi: list[float]
    mpoi_detected: list[float] | None = None
    mpoi_true: list[float] | None = None
    branch: str = "skipped"
    flamed: bool = False
    epmc_true: bool | None = None
    energy: float = 0.0
    body_moves: int = 0
    reason: str | None = None
    p_upper: float | None = None
    expected_energy: float | None = None
    flame_s: float = 0.0


@dataclass
class MissionResult:
    targets: list[TargetResult]
    total_energy: float
    wall_s: float
    aborted: str | None = None
    order: list[str] = field(default_factory=list)
    interrupted: str | None = None  # "SIGINT" / "SIGTERM": the run was stopped from outside

    @property
    def success_rate(self) -> float:
        n = len(self.targets)
        ok = sum(1 for t in self.targets if t.flamed and t.epmc_true is not False)
        return ok / n if n else 0.0

    def to_json(self) -> dict:
        return {
            "targets": [
                {k: v for k, v in asdict(t).items() if k in ("id", "troi", "mpoi_detected", "mpoi_true", "branch", "flamed", "epmc_true", "energy", "body_moves", "reason", "p_upper", "expected_energy", "flame_s")}
                for t in self.targets
            ],
            "total_energy": self.total_energy,
            "success_rate": self.success_rate,
            "wall_s": self.wall_s,
            "aborted": self.aborted,
            "interrupted": self.interrupted is not None,
            "order": self.order,
        }


STALE_WAIT_S = 1.0  # how long a stale arm state (no fresh CAN state frames) is waited out before it counts as a lost link


class Executive:
    def __init__(
        self,
        trois: list[TROI],
        start: SE2,
        end: SE2,
        drivers: DriverSet,
        core: PlanningCore,
        planner: BasePlanner,
        *,
        log=None,
        progress: Callable[[dict], None] | None = None,
        truth: dict[str, tuple[float, float]] | None = None,
        now_ns: Callable[[], int] = time.time_ns,
        timeouts: dict[str, float] | None = None,
        detector: Callable | None = None,
        hook: Callable[[int, str, float], set[str]] | None = None,
        fuel_per_s: float | None = None,
        fuel_reserve: float = FUEL_RESERVE,
    ):
        self.trois = trois
        self.start, self.end = start, end
        self.d = drivers
        self.core = core
        self.robot = core.robot
        self.task = core.task
        self.planner = planner
        self.log = log
        self.progress = progress or (lambda _s: None)
        self.truth = truth or {}
        self.now_ns = now_ns
        self.timeouts = {"body": 60.0, "arm": 20.0, "camera": 5.0, **(timeouts or {})}
        self.view = ViewSolver(self.robot, core.maps, self.task)
        self.flame = FlameSolver(self.robot, self.task)
        self.camera = PinholeCamera.from_config(self.robot.cfg.camera)
        self.detect = detector or detect_centre
        self.total_energy = 0.0
        self._e_start = 0.0  # total_energy when the current target began (its share is logged)
        self._last_tf: tuple | None = None  # (t_ns, body pose, joints) of the last /tf written
        self._phase = "idle"
        self._hook_fn = hook
        self._index = 0
        self._directives: set[str] = set()
        self._flamed_at: list[tuple[str, np.ndarray]] = []  # (target id, the MPOI it was flamed at) in this run
        self._n_skipped = 0  # targets skipped so far (progress lines)
        # fuel budget: a target is begun only if its ξ hold fits above the reserve (FUEL_MARGIN ×
        # the larger of the configured rate and the highest rate measured over this run's holds)
        self.fuel_per_s = fuel_per_s
        self.fuel_reserve = float(fuel_reserve)
        self._fuel_rate_seen = 0.0
        self._unusable_frames = 0  # frames in a row without a usable image (CAMERA_FAULT_FRAMES)

    def _hook(self, phase: str, elapsed_s: float = 0.0) -> None:
        """Bench fault schedule: lets scheduled faults strike at this phase (no-op on the robot)."""
        if self._hook_fn is not None:
            self._directives |= self._hook_fn(self._index, phase, elapsed_s)

    def _take(self, directive: str) -> bool:
        if directive in self._directives:
            self._directives.discard(directive)
            return True
        return False

    # ---- logging helpers -------------------------------------------------------------------
    def _event(self, level: str, msg: str, **kw) -> None:
        if self.log:
            self.log.event(self.now_ns(), level, msg, **kw)

    def _tf(self) -> None:
        """/tf at this instant (before and after every body and arm move); an identical sample at
        the same time as the last one is not written again. During a move, `_tf_body` /
        `_tf_arm` add samples from the driver's state stream (`on_state`)."""
        if self.log:
            try:
                t, pose, q = self.now_ns(), self.d.body.state().pose, tuple(float(v) for v in self.d.arm.state().joints)
            except DriverError:
                return  # no state over a lost link: nothing to draw
            key = (t, pose.as_tuple(), q)
            if key != self._last_tf:
                self._last_tf = key
                self.log.transforms(t, pose, q)

    def _tf_body(self, st) -> None:
        """on_state of a walk: the body's pose on the way (the arm stays as last drawn)."""
        self._tf_moving(pose=st.pose.as_tuple())

    def _tf_arm(self, st) -> None:
        """on_state of an arm move: its joints on the way (the body stays as last drawn)."""
        self._tf_moving(joints=tuple(float(v) for v in st.joints))

    def _tf_moving(self, pose: tuple | None = None, joints: tuple | None = None) -> None:
        """/tf during a move, at most every TF_PERIOD_NS, completing the sample from the last one."""
        if not self.log or self._last_tf is None:
            return
        t = self.now_ns()
        t_last, pose_last, q_last = self._last_tf
        if t - t_last < TF_PERIOD_NS:
            return
        key = (t, pose if pose is not None else pose_last, joints if joints is not None else q_last)
        self._last_tf = key
        self.log.transforms(t, SE2(*key[1]), key[2])

    def _ks(self, tid: str, ks: KeyState, note: str = "") -> None:
        if self.log:
            self.log.key_state(self.now_ns(), tid, self.planner.name, ks, note)
        self._event("info", f"{tid}: key state {ks.label} {note}".strip(), target=tid, key_state=ks.label)

    def _set_phase(self, i: int, n: int, tid: str, phase: str) -> None:
        self._phase = phase
        self.progress({"index": i, "total": n, "target": tid, "phase": phase, "energy": self.total_energy,
                       "flamed": len(self._flamed_at), "skipped": self._n_skipped})

    def _skip(self, i: int, n: int, tid: str, res: TargetResult, reason: str) -> None:
        """A target given up (both visit loops): flame off, the reason recorded, logged and (unless it
        was flamed already) counted and shown to the operator as it happens, then the arm stowed if it can be."""
        self._safe()
        res.reason = reason
        self._event("warning", f"{tid}: skipped ({reason})", target=tid, reason=reason)
        if not res.flamed:
            res.branch = "skipped"
            self._n_skipped += 1
            self.progress({"index": i, "total": n, "target": tid, "phase": f"skipped ({reason})", "energy": self.total_energy,
                           "flamed": len(self._flamed_at), "skipped": self._n_skipped})
        try:
            self._stow()
        except _Skip:
            pass

    def _igniter_state(self, il: IgnitionInterlock | None = None) -> None:
        if not self.log:
            return
        try:
            self._log_igniter(il)
        except DriverError as e:  # a dead link must not stop the record (nor the safing after it)
            self._event("warning", f"igniter state unavailable: {e}")

    def _log_igniter(self, il: IgnitionInterlock | None) -> None:
        g = self.d.igniter.state()
        if il is not None:
            st = il.check()
            self.log.igniter(self.now_ns(), g.flame_on, g.armed, g.fuel, g.fault, st.ok, st.reasons, st.body_stationary, st.epmc_ok, st.estop)
        else:
            b = self.d.body.state()
            self.log.igniter(self.now_ns(), g.flame_on, g.armed, g.fuel, g.fault, False, ["not_flaming"], not b.moving, False, b.estop)

    # ---- motion primitives -----------------------------------------------------------------
    def _safe(self) -> None:
        """Flame off, always first."""
        try:
            self.d.igniter.extinguish()
        except Exception:  # noqa: BLE001 - extinguish must never stop the safing
            pass

    def _stow(self) -> None:
        self._safe()
        st = self.d.arm.state()
        if np.max(np.abs(np.asarray(st.joints) - np.asarray(self.robot.cfg.arm.stow_joints))) < 1e-2 and not st.moving:
            return
        r = self.d.arm.stow(self.timeouts["arm"], on_state=self._tf_arm)
        self._tf()
        if not r.ok and self._arm_fault():
            # a latched arm fault: reset once and retry, as for any arm move (`_arm_to`)
            self._event("warning", f"arm fault {self.d.arm.state().fault} while stowing: reset and retry once")
            self.d.arm.reset(self.timeouts["arm"])
            r = self.d.arm.stow(self.timeouts["arm"], on_state=self._tf_arm)
            self._tf()
        if not r.ok and self._arm_fault():
            # still latched: no target can be reached without walking with the arm out, so every one
            # after would be skipped the same way and the run end "done" (a soak audit: one overcurrent
            # while stowing skipped 17 of 20 targets, exit 0) — the mission aborts instead
            raise MissionAborted(f"arm cannot stow: fault {self.d.arm.state().fault} latched after a reset")
        if not r.ok:
            raise _Skip(f"arm_stow_failed:{r.reason}")

    def _walk(self, goal: SE2, forced: bool = False) -> tuple[SE2, float]:
        """Stow, walk to `goal`; returns (arrived pose, energy of this move)."""
        self._stow()
        before = self.d.body.state().pose
        self._tf()
        r = self.d.body.move_to(goal, self.timeouts["body"], on_state=self._tf_body)
        after = self._settled_pose(r.final)
        self._tf()
        c = energy.cost(before, after, self.task, force_move=forced)
        self.total_energy += c
        self._log_energy()
        if not r.ok:
            raise _Skip(f"body_motion_failed:{r.reason}")
        err = after.distance(goal)
        tol = 2 * self.robot.cfg.body.position_tolerance
        if err > tol:
            # Slipped: arrived off the planned stop (regions are planned with the placement
            # tolerance only). One corrective move, charged like any other.
            self._event("warning", f"{self._tid}: arrived {err:.3f} m off the goal (slip?), correcting once", target=self._tid)
            r = self.d.body.move_to(goal, self.timeouts["body"], on_state=self._tf_body)
            fixed = self._settled_pose(r.final)
            self._tf()
            c2 = energy.cost(after, fixed, self.task)
            self.total_energy += c2
            self._log_energy()
            c += c2
            if not r.ok or fixed.distance(goal) > tol:
                raise _Skip(f"body_off_goal:{fixed.distance(goal):.3f}m")
            after = fixed
        return after, c

    def _log_energy(self) -> None:
        """/energy after every body move: the running total, and the current target's share since
        it began (what summary.json reports as its energy: retries and corrections included)."""
        if self.log:
            self.log.energy(self.now_ns(), self.total_energy, self._tid, self.total_energy - self._e_start, self._moves + 1)

    def _walk_target(self, goal: SE2, forced: bool = False) -> SE2:
        """A walk on behalf of the current target: a motion failure gets one more try from where
        the body stands, then the target is skipped; energy and moves are charged to the target."""
        try:
            pose, c = self._walk(goal, forced)
        except _Skip:
            self._event("warning", f"{self._tid}: body motion failed, re-trying once", target=self._tid)
            pose, c = self._walk(goal, forced)
        self._moves += 1
        return pose

    def _settled_pose(self, final: object, timeout_s: float = 0.5) -> SE2:
        """The body pose after a move, from a state that postdates the arrival: a state stream
        (zenoh, 100 Hz) may still hold a pre-arrival sample when the move's result comes in, and a
        flame pose solved from a stale pose would miss its aim."""
        st = self.d.body.state()
        if not isinstance(final, SE2) or (st.pose.distance(final) < 2e-3 and not st.moving):
            return st.pose
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            time.sleep(0.01)
            st = self.d.body.state()
            if st.pose.distance(final) < 2e-3 and not st.moving:
                break
        return st.pose

    def _body_holds(self) -> None:
        """Before an arm move out to a view or flame pose: the body's link and E-stop. The arm was
        reset and reached out to the flame pose after the body link had latched lost and while the
        robot side E-stopped itself (body and arm never move together, a.2; a timing audit)."""
        b = self.d.body.state()
        self._raise_if_fatal([f"body {b.fault}"] if b.fault else [], b.estop)

    def _arm_to(self, sol: ArmSolution) -> None:
        self._body_holds()
        r = self.d.arm.move_joints(sol.q, self.timeouts["arm"], on_state=self._tf_arm)
        self._tf()
        if not r.ok and self.d.arm.state().fault:
            self._body_holds()
            # A latched arm fault: reset once and retry the move (then give up on the target).
            self._event("warning", f"arm fault {self.d.arm.state().fault}: reset and retry once")
            self.d.arm.reset(self.timeouts["arm"])
            r = self.d.arm.move_joints(sol.q, self.timeouts["arm"], on_state=self._tf_arm)
            self._tf()
        if not r.ok:
            raise _Skip(f"arm_motion_failed:{r.reason}")

    # ---- per target ------------------------------------------------------------------------
    def _observe(
        self, tid: str, troi: TROI, body: SE2, r_eff: float, view_q: np.ndarray | None = None, also: list[TROI] | None = None
    ) -> tuple[np.ndarray | None, dict[str, tuple[float, float]]]:
        """Arm to an NSV pose, capture, detect (the target, and `also` TROIs seen in the same
        image); one re-observation from an adjusted pose. Returns (MPOI or None, also_seen)."""
        also_seen: dict[str, tuple[float, float]] = {}
        planned = body
        for attempt in range(2):
            self._hook("observe")
            body = self._where_now(tid, planned, "the view")
            sol = None
            if self._take("ik_fail"):
                sol = None
            elif view_q is not None and attempt == 0:
                # the planned view, if it still holds from where we stand
                ok, area, T_cam = self.view.nsv(body, np.asarray(view_q, float), np.array(troi.xy), r_eff)
                sol = ArmSolution(np.asarray(view_q, float), T_cam, {"area_ratio": area}) if ok else None
            if sol is None and not (attempt == 0 and "ik_fail" in self._directives):
                sol = self.view.solve(body, troi.xy, r_eff, variant=attempt)
                if sol is None and body is not planned:  # pushed out of the view's reach: back where it was to stand
                    self._event("warning", f"{tid}: no NSV arm pose from where the body was pushed to; walking back", target=tid)
                    body = self._walk_target(planned, forced=True)
                    sol = self.view.solve(body, troi.xy, r_eff, variant=attempt)
            if sol is None:
                self._event("warning", f"{tid}: no NSV arm pose from here (attempt {attempt + 1})", target=tid)
                continue
            self._arm_to(sol)
            self._ks(tid, KeyState("x_e,k2", body, "observe", troi.xy, r_eff), note=f"attempt {attempt + 1}")
            try:
                frame = self.d.camera.capture(self.timeouts["camera"])
            except DriverTimeout as e:
                self._event("warning", f"{tid}: no camera frame ({e}), attempt {attempt + 1}", target=tid)
                self._unusable_frame("no frame arrived")
                continue
            st_b, st_a = self.d.body.state(), self.d.arm.state()
            T_cam = self.robot.T_field_base(st_b.pose) @ st_a.camera_pose
            if self.log:
                self.log.image(self.now_ns(), frame.image, tid)
            miss = self._take("detector_miss")
            if miss and self.log:  # one /detection per attempt, also when a fault replaced the detector
                self.log.detection(self.now_ns(), tid, None, 0.0, "fault_injected", None)
            mpoi, why = (None, "fault_injected") if miss else self._detect_in(frame.image, T_cam, troi, tid)
            if not miss:  # (an injected detector miss says nothing about the camera)
                if why == "bad_image":
                    self._unusable_frame("the detector said bad_image")
                else:
                    self._unusable_frames = 0
            for other in also or []:
                m, _ = self._detect_in(frame.image, T_cam, other, other.id)
                if m is not None:
                    also_seen[other.id] = (float(m[0]), float(m[1]))
            if mpoi is not None:
                return mpoi, also_seen
            self._event("warning", f"{tid}: detection failed ({why}), attempt {attempt + 1}", target=tid, reason=why)
        return None, also_seen

    def _unusable_frame(self, what: str) -> None:
        """Count a frame without a usable image; CAMERA_FAULT_FRAMES in a row abort the mission."""
        self._unusable_frames += 1
        if self._unusable_frames >= CAMERA_FAULT_FRAMES:
            raise MissionAborted(f"camera: {self._unusable_frames} frames in a row without a usable image (last: {what}); "
                                 "check the camera (lens, exposure, colour mode, cable)")

    def _detect_in(self, image: np.ndarray, T_cam: np.ndarray, troi: TROI, tid: str) -> tuple[np.ndarray | None, str | None]:
        """Detect the MPOI of one TROI in an image: (field point via H⁻¹, None), or (None, why).

        Only an answer without a reason is acted on: an "ambiguous" detection carries the best
        guess's pixel (logged), but two near-equal plants in the TROI may as well be the other
        one; the next attempt looks again from another pose instead of flaming a guess."""
        roi = self._roi(T_cam, troi)
        det = self.detect(image, roi=roi)
        mpoi, why = None, det.reason
        if det.pixel is not None and det.reason is None:
            g = self.camera.pixel_to_ground(T_cam, np.array([det.pixel]))[0]
            if np.all(np.isfinite(g)):
                mpoi = g
            else:
                why = "off_ground"
        if self.log:
            self.log.detection(self.now_ns(), tid, det.pixel, det.confidence, det.reason,
                               tuple(mpoi) if mpoi is not None else None, roi.rim())
        return mpoi, why

    def _roi(self, T_cam: np.ndarray, troi: TROI):
        return roi_for(self.camera, T_cam, troi.xy, troi.r)

    def _flame(self, tid: str, body: SE2, mpoi: np.ndarray) -> float:
        """x_e,k3 and the MTC hold under the interlock. A flame-out or a failed ignition gets one
        more trial after a fault reset (burner practice: bounded trials; a second failure stays
        latched); a pushed body gets one re-solved flame pose; an E-stop or an empty tank aborts."""
        reason = "?"
        for attempt in range(2):
            self._hook("flame", 0.0)  # a trial begins: faults meant for the flame pose strike before it is solved
            sol = None if self._take("ik_fail") else flame_solution(self.robot, self.flame, self.core.maps, body, tuple(mpoi))
            if sol is None:
                raise _Skip("no_flame_pose")
            self._arm_to(sol)
            self._ks(tid, KeyState("x_e,k3", body, "flame", tuple(mpoi)), note=f"trial {attempt + 1}")
            il = IgnitionInterlock(self.d, self.robot, self.task, (float(mpoi[0]), float(mpoi[1])))
            il.anchor()
            st = il.check()
            if not st.ok:
                self._safe()
                self._raise_if_fatal(st.reasons, st.estop)
                raise _Skip(f"interlock:{','.join(st.reasons)}")
            self._check_log_written(tid)
            fuel_before = float(self.d.igniter.state().fuel)
            self.d.igniter.arm(self.timeouts["arm"])
            res = self._hold(il)
            flame_s = float(res.extra.get("flame_s", 0.0))
            self._note_fuel_burnt(fuel_before, flame_s)
            if res.ok:
                self._event("info", f"{tid}: flamed {flame_s:.2f} s (ξ = {self.task.xi} s)", target=tid)
                return flame_s
            reason = str(res.reason)
            self._event("warning", f"{tid}: flame trial {attempt + 1} ended: {reason} after {flame_s:.2f} s", target=tid)
            b = self.d.body.state()
            self._raise_if_fatal(il.check().reasons + [reason], b.estop)
            if reason == "fuel_empty":
                raise MissionAborted("igniter: fuel empty")
            if attempt == 0 and reason in ("keepalive_timeout", "bad_frame"):
                # the board tripped (a host stall > 80 ms, or a corrupted command frame) and
                # disarmed itself: arm again for one more trial while the interlock holds
                self._event("warning", f"{tid}: igniter tripped ({reason}); re-arming for one more trial", target=tid)
                self._reset_arm_for_retry(tid)
                continue
            if attempt == 0 and reason in ("ignition_failed", "flame_out"):
                self._event("warning", f"{tid}: resetting the igniter fault ({reason}) for one more trial", target=tid)
                self.d.igniter.reset_fault(self.timeouts["arm"])
                continue
            if attempt == 0 and reason.startswith("permit"):
                body = b.pose  # pushed or moved: re-solve the flame pose from where the body is
                if not self.core.regions.in_R_m(body, mpoi):
                    break
                self._reset_arm_for_retry(tid)
                continue
            break
        raise _Skip(f"flame_failed:{reason}")

    def _reset_arm_for_retry(self, tid: str) -> None:
        """Before a trial's retry: an arm fault the first trial ended with (the gateway latches
        `host_lost` when this host stalls for its heartbeat timeout, as the board trips) is reset
        once; the retry's interlock refused it and skipped the target (a timing audit)."""
        fault = self._arm_fault()
        if fault:
            self._event("warning", f"{tid}: arm fault {fault} after the trial: reset for one more trial", target=tid)
            self.d.arm.reset(self.timeouts["arm"])

    @staticmethod
    def _raise_if_fatal(reasons: list[str], estop: bool) -> None:
        """E-stop or a lost link anywhere ends the mission (igniter already off). A lost link is
        named first: the robot side E-stops itself when its holder's check-ins stop, so an E-stop
        seen with a lost link is most likely that one, not a button pressed (a timing audit)."""
        lost = [r for r in reasons if "link_lost" in r or "state_unavailable" in r]
        if lost:
            raise LinkLost(f"link lost ({', '.join(lost)})" + ("; the body is E-stopped" if estop else ""))
        if estop:
            raise EStopActive("E-stop engaged")

    def _hold(self, il: IgnitionInterlock):
        """ignite(ξ) with keep-alives permitted only while the interlock holds; flame off after."""
        last = [0]
        t_start = [None]

        def permit() -> bool:
            t = self.now_ns()
            if t_start[0] is None:
                t_start[0] = t
            self._hook("flame", (t - t_start[0]) * 1e-9)
            t = self.now_ns()  # the check's own time: a bench fault may have let time pass (a host stall)
            s = il.check()
            if self.log and (t - last[0] > 50_000_000 or not s.ok):  # ≤ 20 Hz, and every denial
                last[0] = t
                g = self.d.igniter.state()
                self.log.igniter(t, g.flame_on, g.armed, g.fuel, g.fault, s.ok, s.reasons, s.body_stationary, s.epmc_ok, s.estop)
            return s.ok

        self._igniter_state(il)
        last[0] = self.now_ns()  # that sample is the hold's first: permit() logs from 50 ms on
        try:
            return self.d.igniter.ignite(self.task.xi, permit, timeout=self.task.xi + 10.0)
        finally:
            self._safe()
            self.d.igniter.disarm()
            self._igniter_state(il)

    def _fuel_need(self) -> float:
        """Tank fraction one ξ hold is expected to burn (0 while no rate is known)."""
        return hold_fuel(self.task.xi, max(self.fuel_per_s or 0.0, self._fuel_rate_seen))

    def _check_log(self, tid: str) -> None:
        """Begin a target only while its record can be kept: a run log that stopped taking writes
        (disk full) would leave the burns that follow unrecorded. Raises MissionAborted."""
        err = getattr(self.log, "write_error", None) if self.log else None
        if err:
            raise MissionAborted(f"run log: cannot write ({err}); {tid} and later targets not begun")

    def _check_log_written(self, tid: str) -> None:
        """Burn only what the log holds: its open chunk (this target's detection, image and key
        states) is handed to the OS first. A failed write shows only when a chunk is flushed (every
        0.5 s or 256 KiB), so a disk that filled since the target began let it be flamed with no
        record (a soak audit: with a 20 kB file limit, the first target walked, looked and burnt
        unlogged). Raises MissionAborted, the flame never lit."""
        flush = getattr(self.log, "flush", None)
        if flush is not None:
            flush()
        err = getattr(self.log, "write_error", None) if self.log else None
        if err:
            self._safe()
            raise MissionAborted(f"run log: cannot write ({err}); {tid} not flamed, later targets not begun")

    def _check_igniter(self, tid: str) -> None:
        """Begin a target only with an igniter that can light: a fault still latched here is one
        the bounded trials left (a second failure to light, a flame-out on the retry), and the
        interlock would deny every later hold after a walk and a look. Raises MissionAborted."""
        fault = self.d.igniter.state().fault
        if fault and "link_lost" in fault:
            raise LinkLost(f"igniter link lost ({fault})")
        if fault:
            raise MissionAborted(f"igniter: fault latched ({fault}) after the bounded trials; {tid} and later targets not begun")

    def _arm_fault(self) -> str | None:
        """The arm's latched fault, or None. A state gone stale (the CAN arm's joint or status
        frames older than 0.25 s: `state_stale`) is not one a reset clears (the reset would only
        disable a healthy arm): it is waited out for up to STALE_WAIT_S, then taken as a lost link."""
        fault = self.d.arm.state().fault
        deadline = time.monotonic() + STALE_WAIT_S
        while fault == "state_stale" and time.monotonic() < deadline:
            time.sleep(0.02)
            fault = self.d.arm.state().fault
        if fault == "state_stale" or (fault and "link_lost" in fault):
            raise LinkLost(f"arm link lost ({fault})")
        return fault

    def _check_arm(self, tid: str) -> None:
        """Begin a target only with an arm that can move: a fault still latched here is one the
        last target's reset and retry left; one more reset, and if it holds, every later target
        would be walked to and skipped at its first arm move (a run ending 'done', exit 0).
        Raises MissionAborted."""
        fault = self._arm_fault()
        if fault:
            self._event("warning", f"arm fault {fault} latched before {tid}: reset once")
            self.d.arm.reset(self.timeouts["arm"])
            fault = self.d.arm.state().fault
            if fault:
                raise MissionAborted(f"arm: fault latched ({fault}) after a reset; {tid} and later targets not begun")

    def _check_fuel(self, tid: str) -> None:
        """Begin a target only with its flame hold's fuel above the reserve: aborting here, before
        the walk, leaves the tank's last fuel unplanned and no weed half-burnt (a run-dry mid-hold
        would). Raises MissionAborted."""
        fuel = float(self.d.igniter.state().fuel)
        need = self._fuel_need()
        if fuel - need <= self.fuel_reserve:
            what = f", a hold needs ~{need:.1%}" if need > 0 else ""
            raise MissionAborted(f"igniter: fuel low ({fuel:.1%} left{what}, reserve {self.fuel_reserve:.1%}); "
                                 f"{tid} and later targets not begun")

    def _note_fuel_burnt(self, fuel_before: float, flame_s: float) -> None:
        """Learn the tank's consumption from a hold (the highest rate seen is kept)."""
        if flame_s < 0.5:
            return
        try:
            burnt = fuel_before - float(self.d.igniter.state().fuel)
        except Exception:  # noqa: BLE001 - a state read failing here is handled by the next check
            return
        if burnt > 0:
            self._fuel_rate_seen = max(self._fuel_rate_seen, burnt / flame_s)

    def _target(self, i: int, n: int, troi: TROI, x_kmax: SE2, res: TargetResult) -> None:
        tid = troi.id
        self._tid = tid
        self._e_start = self.total_energy
        self._moves = 0
        here = self.d.body.state().pose
        self._set_phase(i, n, tid, "plan")
        plan: Plan = self.planner.plan(here, x_kmax, troi)
        res.p_upper = plan.p_upper
        res.expected_energy = plan.expected_cost
        if self.log:
            self.log.plan(self.now_ns(), tid, plan)
            self.log.regions(self.now_ns(), tid, troi, list(self.core.ro(troi.r).intervals), list(self.core.rm.intervals), None)
        self._ks(tid, KeyState("x_k0", here))

        self._set_phase(i, n, tid, "walk to x_b,k1")
        self._hook("walk")
        self._check_log(tid)
        self._check_igniter(tid)
        self._check_arm(tid)
        self._check_fuel(tid)
        x1 = self._walk_target(plan.x_b_k1)
        self._ks(tid, KeyState("x_b,k1", x1))
        if self.planner.name == "a":
            mpoi = np.array(troi.xy)  # deterministic: assume X̄_w = X_w, no look
        else:
            self._set_phase(i, n, tid, "observe")
            mpoi, _ = self._observe(tid, troi, x1, self.core.effective_radius(troi.r))
            if mpoi is None:
                raise _Skip("detection_failed")
        res.mpoi_detected = [float(mpoi[0]), float(mpoi[1])]
        if self.log:
            self.log.regions(self.now_ns(), tid, troi, list(self.core.ro(troi.r).intervals), list(self.core.rm.intervals), tuple(mpoi))
        self._check_not_flamed(tid, mpoi)
        body = self._where_now(tid, x1)
        upper = self.planner.name != "b" and bool(self.core.regions.in_R_m(body, mpoi))
        if upper and flame_solution(self.robot, self.flame, self.core.maps, body, tuple(mpoi)) is None:
            upper = False  # the map says yes but IK from the actual pose says no: reposition
        res.branch = "upper" if upper else "lower"
        if not upper:
            self._set_phase(i, n, tid, "reposition x_b,k3")
            for attempt in range(2):
                here = self.d.body.state().pose
                P3 = self.planner._replan_k3(self.core.base_xy(here), self.core.base_xy(x_kmax), mpoi)
                x3 = self.core.facing(P3, mpoi)
                self._ks(tid, KeyState("x_b,k3", x3), note="re-plan" if attempt else "")
                self._hook("reposition")
                body = self._walk_target(x3, forced=True)
                if flame_solution(self.robot, self.flame, self.core.maps, body, tuple(mpoi)) is not None:
                    break
                self._event("warning", f"{tid}: no flame pose after reposition, re-planning once", target=tid)
            else:
                raise _Skip("no_flame_pose_after_replan")
        self._flame_stow(i, n, tid, body, mpoi, res)

    def _where_now(self, tid: str, planned: SE2, what: str = "the flame pose") -> SE2:
        """The body's pose for an arm solve: `planned` (where it arrived) unless it has moved
        since by more than the placement tolerance (pushed or slid while the arm worked), then
        where it stands. An arm pose solved for where the body was looks or aims beside the weed
        (and the interlock, which checks from the measured pose, would refuse the flame)."""
        here = self.d.body.state().pose
        tol = self.robot.cfg.body.position_tolerance
        if here.distance(planned) <= tol and abs(float(wrap_angle(here.yaw - planned.yaw))) <= 0.02:
            return planned
        self._event("warning", f"{tid}: the body moved {here.distance(planned):.3f} m since it arrived; "
                               f"{what} is solved from where it stands", target=tid)
        return here

    def _check_not_flamed(self, tid: str, mpoi: np.ndarray) -> None:
        """Skip a target whose detected centre is one this run has flamed already (within
        `aim_tolerance`, what the flame covers): overlapping TROIs, or a prescan listing one weed
        twice, whose looks found the same plant. Flaming it again burns fuel on ash and reports a
        second weed flamed where one was."""
        if not self._flamed_at:
            return
        d = np.hypot(*(np.array([at for _, at in self._flamed_at]) - np.asarray(mpoi, float)).T)
        k = int(np.argmin(d))
        if d[k] <= self.aim_tolerance:
            other = self._flamed_at[k][0]
            self._event("warning", f"{tid}: its centre is {other}'s, flamed already ({100 * d[k]:.1f} cm away)",
                        target=tid, same_as=other)
            raise _Skip("already_flamed")

    def _flame_stow(self, i: int, n: int, tid: str, body: SE2, mpoi: np.ndarray, res: TargetResult) -> None:
        """Flame from `body` at the detected MPOI, stow, and score EPMC against the truth (bench)."""
        self._set_phase(i, n, tid, "flame")
        res.flame_s = self._flame(tid, body, mpoi)
        res.flamed = True
        self._flamed_at.append((tid, np.array(mpoi, float)))
        self._hook("stow")
        self._stow()
        if tid in self.truth:
            res.epmc_true = bool(self._epmc_true(body, mpoi, np.asarray(self.truth[tid])))

    def _epmc_true(self, body: SE2, aimed: np.ndarray, true_xy: np.ndarray) -> bool:
        """Bench check: the flame pose used (aimed at the detected MPOI) against the true MPOI.

        EPMC holds when ‖X_e − X̄_w,true‖² ∈ [ε_min, ε_max] and the flame axis passes within the
        detection tolerance of the true centre (a flame aimed 5 cm off misses a weed's centre).
        """
        sol = flame_solution(self.robot, self.flame, self.core.maps, body, tuple(aimed))
        if sol is None:
            return False
        X_e, axis = sol.T_field_frame[:3, 3], sol.T_field_frame[:3, 0]
        t3 = np.array([true_xy[0], true_xy[1], 0.0])
        d2 = float(np.sum((t3 - X_e) ** 2))
        # distance of the true centre from the flame axis
        v = t3 - X_e
        off = float(np.linalg.norm(v - (v @ axis) * axis))
        return self.task.eps_min <= d2 <= self.task.eps_max and off <= self.aim_tolerance

    aim_tolerance = 0.03  # m: the flame must pass within 3 cm of the true centre

    # ---- field planner: one loop over the planner's own sequence ---------------------------
    def _field_target(self, i: int, n: int, plan: Plan, res: TargetResult) -> None:
        """A target under the field planner: its stops may be shared with the previous and next
        targets (no walk to a midpoint; x_kmax = the flame pose), its view may reveal other MPOIs,
        and a target whose MPOI is already known has no observation stop."""
        fp = self.planner
        troi, tid = plan.troi, plan.troi.id
        self._tid, self._moves, self._e_start = tid, 0, self.total_energy
        res.p_upper, res.expected_energy = plan.p_upper, plan.expected_cost
        if self.log:
            self.log.plan(self.now_ns(), tid, plan)
        here = self.d.body.state().pose
        self._ks(tid, KeyState("x_k0", here))
        x1 = plan.x_b_k1
        self._set_phase(i, n, tid, "walk to x_b,k1")
        self._hook("walk")
        self._check_log(tid)
        self._check_igniter(tid)
        self._check_arm(tid)
        self._check_fuel(tid)
        if here.distance(x1) > self.robot.cfg.body.position_tolerance or abs(here.yaw - x1.yaw) > 0.02:
            x1 = self._walk_target(x1)
        else:
            x1 = here
        self._ks(tid, KeyState("x_b,k1", x1))
        if plan.state("x_e,k2") is not None:
            self._set_phase(i, n, tid, "observe")
            also = [fp.trois[k] for k in plan.terms.get("also_observe", []) if k in fp.trois]
            mpoi, also_seen = self._observe(tid, troi, x1, self.core.effective_radius(troi.r), plan.terms.get("view_q"), also)
            fp.observed(tid, None if mpoi is None else (float(mpoi[0]), float(mpoi[1])), also_seen)
            if mpoi is None:
                raise _Skip("detection_failed")
            if also_seen:
                self._event("info", f"{tid}: the same view revealed {sorted(also_seen)}", target=tid)
        else:
            mpoi = np.array(fp.known[tid])
        res.mpoi_detected = [float(mpoi[0]), float(mpoi[1])]
        self._check_not_flamed(tid, mpoi)
        out = fp.after_observation(plan, mpoi)
        res.branch = out.branch
        body = self._where_now(tid, x1)
        k3 = next((k for k in out.key_states if k.label == "x_b,k3"), None)
        if k3 is None and body is not x1 and flame_solution(self.robot, self.flame, self.core.maps, body, tuple(mpoi)) is None:
            # moved since the look (pushed) out of the flame pose's reach: back to where it looked from
            k3 = KeyState("x_b,k3", x1)
        if k3 is not None:
            self._set_phase(i, n, tid, "reposition x_b,k3")
            self._ks(tid, k3)
            self._hook("reposition")
            body = self._walk_target(k3.body, forced=True)
        self._flame_stow(i, n, tid, body, mpoi, res)

    def _run_field(self, results: dict[str, TargetResult]) -> list[str]:
        fp = self.planner
        order: list[str] = []
        i = 0
        while True:
            plan = fp.next_plan(self.d.body.state().pose, {})
            if plan is None:
                break
            tid = plan.troi.id
            order.append(tid)
            self._index = i
            res = results[tid]
            e0 = self.total_energy
            try:
                self._field_target(i, len(results), plan, res)
            except _Skip as s:
                self._skip(i, len(results), tid, res, s.reason)
            finally:  # also when the mission aborts on this target: what it spent is reported
                res.energy = self.total_energy - e0
                res.body_moves = self._moves
            fp.done(tid, res.flamed)
            i += 1
        here = self.d.body.state().pose
        if here.distance(self.end) > self.robot.cfg.body.position_tolerance:
            self._set_phase(i, len(results), "-", "walk to end")
            self._tid, self._moves, self._e_start = "", 0, self.total_energy
            self._walk(self.end)
        return order

    # ---- the mission -----------------------------------------------------------------------
    def run(self) -> MissionResult:
        if getattr(self.planner, "name", "") == "field":
            return self._run_with(self._field_order)
        return self._run_with(None)

    def _field_order(self) -> list[TROI]:
        return self.planner.start(self.trois, self.start, self.end)

    def _run_with(self, field_order) -> MissionResult:
        t0 = time.perf_counter()

        def results_of(order: list[TROI]) -> list[TargetResult]:
            return [TargetResult(t.id, [t.x, t.y, t.r], mpoi_true=list(map(float, self.truth[t.id])) if t.id in self.truth else None)
                    for t in order]

        # the targets in the mission's order until the visit order is known: ordering thousands of
        # targets takes seconds, and a run interrupted (or failing) then is reported like any other
        ordered = list(self.trois)
        results = results_of(ordered)
        self._tid, self._moves, self._e_start = "", 0, 0.0
        aborted = interrupted = None
        late = HeldSignals()  # the first interrupt raises; any later one (and all from the end of the targets on) is held
        try:  # (outer: a stop signal that lands while an abort below is being handled, before `late` holds them)
            try:
                late.start(raise_first=True)
                self._set_phase(0, len(self.trois), "-", "ordering")  # (thousands of targets: seconds before the first)
                ordered = field_order() if field_order else order_trois(self.trois, self.start.xy, self.end.xy)
                results = results_of(ordered)
                if self.log:
                    for t in ordered:
                        if t.id in self.truth:
                            self.log.truth_mpoi(self.now_ns(), t.id, tuple(self.truth[t.id]))
                self._event("info", f"mission start: {len(ordered)} targets, planner {self.planner.name}", order=[t.id for t in ordered])
                self._check_startup()
                if field_order is not None:
                    by_id = {r.id: r for r in results}
                    visited = self._run_field(by_id)
                    results = [by_id[t] for t in visited] + [r for r in results if r.id not in visited]
                    ordered = [next(t for t in self.trois if t.id == r.id) for r in results]
                for i, troi in enumerate(ordered if field_order is None else []):
                    self._index = i
                    x_kmax = x_kmax_of(ordered, i, self.end)
                    res = results[i]
                    e0 = self.total_energy
                    try:
                        self._target(i, len(ordered), troi, x_kmax, res)
                        self._set_phase(i, len(ordered), troi.id, "walk to x_kmax")
                        self._walk(x_kmax)
                        self._moves += 1
                        self._ks(troi.id, KeyState("x_kmax", self.d.body.state().pose))
                    except _Skip as s:
                        self._skip(i, len(ordered), troi.id, res, s.reason)
                    finally:  # also when the mission aborts on this target: what it spent is reported
                        res.energy = self.total_energy - e0
                        res.body_moves = self._moves
            except (LinkLost, EStopActive, MissionAborted, DriverError) as e:
                late.start()  # (any signal from here on is noted)
                aborted = f"{type(e).__name__}: {e}"
            except Exception as e:  # noqa: BLE001 - a software fault mid-mission (a planner on a degenerate
                # robot/task): the robot is made safe and the run recorded like any abort, traceback in the log
                late.start()  # (any signal from here on is noted)
                aborted = f"internal error: {type(e).__name__}: {' '.join(str(e).split())[:200]}"
                self._event("error", "".join(traceback.format_exception(e))[-8000:])
            except KeyboardInterrupt as e:  # Ctrl-C, SIGTERM or SIGHUP (`late` raises the first): ended like an
                interrupted = str(e) or "SIGINT"  # abort and recorded; a second one is noted, not raised
                aborted = f"interrupted ({interrupted})"
        except KeyboardInterrupt as e:
            late.start()
            interrupted = str(e) or "SIGINT"
            aborted = f"{aborted}; interrupted ({interrupted})" if aborted else f"interrupted ({interrupted})"
        except BaseException:  # not ours to end (SystemExit …): only made safe
            late.stop()
            self._safe()
            raise
        late.start()
        try:
            self._end(results, len(ordered), aborted, interrupted, late)
        finally:
            late.stop()
        return MissionResult(results, self.total_energy, time.perf_counter() - t0, aborted, [t.id for t in ordered], interrupted)

    def _end(self, results: list, n: int, aborted: str | None, interrupted: str | None, late: HeldSignals) -> None:
        """The ending of every run, with Ctrl-C / SIGTERM held (`late`): flame off, then for an
        abort body stop and (not after an interrupt) arm stow, the final igniter state."""
        self._safe()
        if aborted:
            self._event("error", f"mission aborted: {aborted}")
            try:
                self.d.body.stop()
            except Exception:  # noqa: BLE001
                pass
            try:
                # stopped from outside: no new arm motion the operator did not ask for
                if not interrupted and not late.received:
                    self.d.arm.stow(self.timeouts["arm"])
            except Exception:  # noqa: BLE001 - stow "if possible"
                pass
            if interrupted:
                self._event("warning", f"mission interrupted ({interrupted}): flame off, body stopped, arm left where it is")
            for r in results:
                if r.reason is None and not r.flamed:
                    r.reason = "mission_aborted"
        else:
            try:
                self._set_phase(n, n, "-", "done")
            except Exception:  # noqa: BLE001
                pass
            self._event("info", f"mission done: energy {self.total_energy:.3f}")
        self._igniter_state()
        if late.received:
            self._event("warning", f"{', '.join(late.received)} during the run's ending: noted; the ending was finished")

    def _check_startup(self) -> None:
        b = self.d.body.state()
        if b.fault and b.fault.startswith("link_lost"):  # (before the E-stop it may have caused)
            raise LinkLost(f"body {b.fault} at mission start")
        if b.estop:
            raise EStopActive("E-stop engaged at mission start")
        self._safe()
        self._stow()
        need = self._fuel_need()
        if need > 0:
            fuel = float(self.d.igniter.state().fuel)
            holds = holds_left(fuel, self.fuel_reserve, need)
            if holds < len(self.trois):
                self._event("warning", f"fuel {fuel:.1%} (reserve {self.fuel_reserve:.1%}) is enough for about {holds} "
                                       f"of {len(self.trois)} targets; the mission stops before the first that does not fit")
