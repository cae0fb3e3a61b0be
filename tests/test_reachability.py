import math

import numpy as np

from capm_field.camera import PinholeCamera
from capm_field.config import ReachabilityConfig, TaskConfig
from capm_field.geometry import SE2
from capm_field.reachability import FlameSolver, RadialSet, get_maps, problem_type


def test_default_problem_is_type_ii(maps):
    ro, rm = maps.observe_map(0.25).radial_set(0.0), maps.manip.radial_set(0.0)
    assert not ro.empty and not rm.empty
    assert problem_type(ro, rm) == "II"
    # The robot can neither see nor flame under its own body (keep-out cylinder).
    assert rm.inner >= 0.3 and ro.inner >= 0.3


def test_problem_types_from_annuli():
    assert problem_type(RadialSet(((1.0, 2.0),)), RadialSet(((0.2, 0.6),))) == "I"
    assert problem_type(RadialSet(((0.5, 1.5),)), RadialSet(((0.3, 0.9),))) == "II"
    assert problem_type(RadialSet(((0.2, 0.5),)), RadialSet(((0.8, 1.2),))) == "III"
    assert problem_type(RadialSet(((1.0, 2.0),)), RadialSet(((0.2, 0.6),)), mpoi_offset=0.3, r_w=0.25) == "IV"


def _direct_flame_feasible(robot, solver, body, target_xy, rng) -> bool:
    """Independent check: IK from many random seeds, validated by the same task constraints."""
    T = robot.T_field_base(body)
    tgt = np.linalg.inv(T) @ np.array([target_xy[0], target_xy[1], 0.0, 1.0])
    seeds = [rng.uniform(robot.lower, robot.upper) for _ in range(10)] + solver.seeds(tgt[:3], n=6)
    for t in np.linspace(solver.t_lo + 0.005, solver.t_hi - 0.005, 4):
        for q0 in seeds:
            q, ok, _ = robot.ik_axis_point("nozzle", tgt[:3], t, q0, iters=80, tol=5e-4)
            if ok and solver.valid(q, tgt[:3]):
                return True
    return False


def test_R_m_membership_agrees_with_direct_ik(robot, task, regions, maps):
    rng = np.random.default_rng(7)
    solver = FlameSolver(robot, task, bank_steps=(10, 10, 7, 5))
    rm = maps.manip.radial_set(None)
    agree = total = 0
    for _ in range(60):
        body = SE2(rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-math.pi, math.pi))
        r, bearing = rng.uniform(0.1, 1.1), rng.uniform(-2.4, 2.4)  # inside joint 1's range
        base = robot.arm_base_xy(body)
        target = base + r * np.array([math.cos(body.yaw + bearing), math.sin(body.yaw + bearing)])
        if min(abs(r - a) for iv in rm.intervals for a in iv) < 0.02:
            continue  # within a map bin of the boundary: either answer is within resolution
        total += 1
        agree += bool(regions.in_R_m(body, target)) == _direct_flame_feasible(robot, solver, body, target, rng)
    assert total >= 40
    assert agree / total >= 0.95, f"{agree}/{total}"


def test_R_o_membership_agrees_with_direct_view_check(robot, task, regions, maps):
    """A body pose in R_o must admit a camera pose (found by IK) with NSV for the TROI; and poses
    well outside R_o must not (sampled over arm configurations)."""
    cam = PinholeCamera.from_config(robot.cfg.camera)
    rng = np.random.default_rng(3)
    ro = maps.observe_map(0.25).radial_set(0.0)
    checked = agree = 0
    for _ in range(25):
        r = rng.uniform(0.2, 1.8)
        if min(abs(r - a) for iv in ro.intervals for a in iv) < 0.05:
            continue
        body = SE2(0.0, 0.0, 0.0)
        target = np.array([r, 0.0])
        inside = bool(regions.in_R_o(body, target, 0.25))
        found = False
        T = robot.T_field_base(body)
        for depth in np.linspace(0.5, 1.6, 12):
            for q0 in [rng.uniform(robot.lower, robot.upper) for _ in range(6)]:
                q, ok, _ = robot.ik_axis_point("camera", np.array([r, 0.0, -robot.height]), depth, q0, iters=80, tol=1e-3)
                if not ok or not robot.config_valid(q):
                    continue
                Tc = T @ robot.frame_pose(q, "camera")
                cov, area = cam.disc_view(Tc, target, 0.25)
                c_base = robot.frame_pose(q, "camera")[:3, 3]
                ring = [np.array([r + 0.25 * math.cos(a), 0.25 * math.sin(a), -robot.height]) for a in np.linspace(0, 2 * math.pi, 8, endpoint=False)]
                clear = not any(robot.segment_blocked(c_base, p) for p in ring)
                if cov and area >= task.delta and clear:
                    found = True
                    break
            if found:
                break
        checked += 1
        agree += inside == found
    assert checked >= 15
    assert agree / checked >= 0.9, f"{agree}/{checked}"


def test_maps_cache_round_trip(tmp_path, robot):
    rc = ReachabilityConfig(joint_steps=(8, 8, 5, 3), roll_steps=2, radial_step=0.04, cache_dir=str(tmp_path), troi_radius_max=0.3, troi_radius_step=0.05)
    task = TaskConfig()
    built = get_maps(robot, task, rc)
    files = list(tmp_path.glob("reach-*.npz"))
    assert len(files) == 1 and built.key in files[0].name
    loaded = get_maps(robot, task, rc)
    np.testing.assert_array_equal(built.manip.lo, loaded.manip.lo)
    np.testing.assert_array_equal(built.observe[2].hi, loaded.observe[2].hi)
    # A different task threshold is a different cache entry.
    other = get_maps(robot, TaskConfig(delta=0.2), rc)
    assert other.key != built.key and len(list(tmp_path.glob("reach-*.npz"))) == 2
    # A corrupt cache file is rebuilt, not fatal.
    files[0].write_bytes(b"not a zip")
    again = get_maps(robot, task, rc)
    np.testing.assert_array_equal(again.manip.lo, built.manip.lo)


def test_saves_of_the_same_maps_at_once_do_not_share_a_temporary_file(tmp_path, maps):
    """Two processes building the same maps (a run and a bench, tests side by side) wrote into
    one `.tmp.npz`; each save now has its own, and the cache left is whole."""
    from concurrent.futures import ThreadPoolExecutor

    from capm_field.reachability import load_maps, save_maps

    path = tmp_path / f"reach-{maps.key}.npz"
    with ThreadPoolExecutor(4) as pool:
        list(pool.map(lambda _: save_maps(maps, path), range(8)))
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]
    np.testing.assert_array_equal(load_maps(path, maps.key).manip.lo, maps.manip.lo)


def test_flame_solver_solution_satisfies_epmc(robot, task):
    solver = FlameSolver(robot, task)
    target = np.array([0.6, 0.1, -robot.height])
    q, t = solver.solve(target)
    T = robot.frame_pose(q, "nozzle")
    d2 = float(np.sum((T[:3, 3] - target) ** 2))
    assert task.eps_min - 1e-6 <= d2 <= task.eps_max + 1e-6  # EPMC: ‖X_e − X̄_w‖² ∈ [ε_min, ε_max]
    assert robot.config_valid(q)
    assert solver.solve(np.array([1.6, 0.0, -robot.height])) is None  # out of reach


def test_maps_cache_key_follows_the_urdf_contents_not_its_name(tmp_path, robot, task):
    """An edited URDF at the same path read back the old file's maps; a byte-identical copy
    elsewhere (a mission moved to another directory) rebuilt maps it already had."""
    from capm_field.config import RobotConfig
    from capm_field.reachability import maps_key
    from capm_field.robot_model import RobotModel, default_urdf_path

    rc = ReachabilityConfig()
    copy = tmp_path / "z1.urdf"
    copy.write_bytes(default_urdf_path().read_bytes())
    arm = RobotConfig().arm.model_copy(update={"urdf": str(copy)})
    moved = RobotModel(RobotConfig().model_copy(update={"arm": arm}))
    assert maps_key(moved, task, rc) == maps_key(robot, task, rc)
    text = copy.read_text()
    assert text.count('xyz="0 0 0.045"') == 1
    copy.write_text(text.replace('xyz="0 0 0.045"', 'xyz="0 0 0.055"'))  # joint 2 one centimetre higher
    assert maps_key(RobotModel(RobotConfig().model_copy(update={"arm": arm})), task, rc) != maps_key(robot, task, rc)
