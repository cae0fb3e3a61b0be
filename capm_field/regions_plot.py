"""`capm-field regions`: draw R_o, R_m and their overlap to a PNG (like the paper's Fig. 4–5).

Regions are sets of body (arm-base) positions around the target, computed from the Z1 URDF:
blue R_o(R_w^TROI) for the given TROI radius, green R_m(X̄_w) for an MPOI at the chosen offset,
and their overlap, where one stop serves both observation and flaming. Also prints the annulus
summary and the paper's problem type.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from . import cli_args
from .config import TASK_FLAGS, ArmConfig, ReachabilityConfig, RobotConfig, TaskConfig, build
from .errors import UserError, check_output
from .reachability import get_maps, problem_type
from .robot_model import RobotModel

RESOLUTION_RANGE = (0.001, 0.1)  # m: finer is a multi-GiB raster, coarser is a handful of cells
MAX_CELLS = 2000  # raster cells across (the float image is 2000² × 3 × 8 B ≈ 100 MB at most)


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="capm-field regions", description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="regions.png", help="PNG file to write")
    ap.add_argument("--radius", type=float, default=0.25, help="TROI radius r_w (m)")
    ap.add_argument("--mpoi-offset", type=float, default=0.0, help="distance of X̄_w from X_w along +x (m, ≥ 0)")
    ap.add_argument("--delta", type=float, default=TaskConfig().delta, help="δ (NSV resolution threshold)")
    ap.add_argument("--eps-min", type=float, default=TaskConfig().eps_min)
    ap.add_argument("--eps-max", type=float, default=TaskConfig().eps_max)
    ap.add_argument("--urdf", type=cli_args.path, help="Z1 URDF (default: the one shipped in example-robot-data)")
    ap.add_argument("--resolution", type=float, default=0.01,
                    help=f"raster cell of the drawing (m, {RESOLUTION_RANGE[0]:g} to {RESOLUTION_RANGE[1]:g}, "
                         f"at most {MAX_CELLS} cells across)")
    return ap


MAX_MPOI_OFFSET = 10.0  # m: X̄_w that far from X_w is another field (the regions reach ~1.3 m)


def main(argv: list[str]) -> int:
    a = _parser().parse_args(argv)
    check_output(a.out, "--out")
    if not a.radius > 0:  # (nan too)
        raise UserError(f"--radius must be positive, got {a.radius}")
    # 0 divided by zero, a negative cell indexed an empty raster, 1e-9 asked for 25 GiB
    lo, hi = RESOLUTION_RANGE
    if not lo <= a.resolution <= hi:
        raise UserError(f"--resolution must be in [{lo:g}, {hi:g}] m, got {a.resolution:g}")
    if not 0 <= a.mpoi_offset <= MAX_MPOI_OFFSET:  # nan drew a PNG without R_m; 1e308 overflowed (warnings)
        raise UserError(f"--mpoi-offset must be a finite distance in [0, {MAX_MPOI_OFFSET:g}] m, got {a.mpoi_offset:g}")
    if not a.out.lower().endswith(".png"):
        raise UserError(f"--out must name a .png file, got {a.out!r}")
    task = build(TaskConfig, "task", TASK_FLAGS, delta=a.delta, eps_min=a.eps_min, eps_max=a.eps_max)
    robot = RobotModel(RobotConfig(arm=ArmConfig(urdf=a.urdf)) if a.urdf else RobotConfig())
    maps = get_maps(robot, task, ReachabilityConfig(), progress=lambda m: print(f"reachability maps: {m}", file=sys.stderr))
    try:
        ro_map = maps.observe_map(a.radius)
    except ValueError as e:
        raise UserError(f"--radius: {e}") from e
    rm_map = maps.manip

    # Raster of arm-base positions around X_w = origin. A position P sees the target at bearing
    # 0 when the body faces it, so membership is by distance (and bearing 0) in each map.
    ext = max(float(np.nanmax(np.where(np.isfinite(ro_map.lo), (np.arange(len(ro_map.lo)) + 1) * ro_map.step, np.nan), initial=1.0)), 1.0) + 0.3
    if 2 * ext / a.resolution > MAX_CELLS:
        raise UserError(f"--resolution {a.resolution:g} m makes a raster of {2 * ext / a.resolution:.0f} cells across "
                        f"(limit {MAX_CELLS}): use at least {2 * ext / MAX_CELLS:.4f} m")
    g = np.arange(-ext, ext, a.resolution)
    X, Y = np.meshgrid(g, g)
    in_o = ro_map.contains(np.hypot(X, Y), np.zeros_like(X))
    in_m = rm_map.contains(np.hypot(X - a.mpoi_offset, Y), np.zeros_like(X))
    img = np.ones(X.shape + (3,))
    img[in_o] = (0.62, 0.78, 0.95)
    img[in_m] = (0.55, 0.80, 0.55)
    img[in_o & in_m] = (0.25, 0.55, 0.45)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Patch

    ro, rm = ro_map.radial_set(0.0), rm_map.radial_set(0.0)
    kind = problem_type(ro, rm, a.mpoi_offset, a.radius)
    fig, ax = plt.subplots(figsize=(6.5, 6.5), dpi=120)
    ax.imshow(img, origin="lower", extent=(g[0], g[-1], g[0], g[-1]))
    ax.add_patch(Circle((0, 0), a.radius, fill=False, ls="--", color="k", lw=1))
    ax.plot([0], [0], "k+", ms=10)
    ax.plot([a.mpoi_offset], [0], "r*", ms=12)
    ax.legend(
        handles=[
            Patch(color=(0.62, 0.78, 0.95), label=f"R_o (r_w={a.radius:.2f} m): {_fmt(ro)}"),
            Patch(color=(0.55, 0.80, 0.55), label=f"R_m: {_fmt(rm)}"),
            Patch(color=(0.25, 0.55, 0.45), label="R_o ∩ R_m"),
        ],
        loc="upper right",
        fontsize=8,
    )
    ax.set_title(f"Body (arm-base) positions around the TROI — problem type {kind}\nδ={a.delta}, ε=[{a.eps_min}, {a.eps_max}] m², h={robot.height} m")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    fig.tight_layout()
    try:
        fig.savefig(a.out)
    except OSError as e:
        raise UserError(f"cannot write --out {a.out!r}: {e.strerror or e}") from None
    plt.close(fig)
    area = a.resolution**2
    print(f"R_o(r_w={a.radius}): {_fmt(ro)}   R_m: {_fmt(rm)}   type {kind}")
    print(f"areas: R_o {in_o.sum() * area:.2f} m², R_m {in_m.sum() * area:.2f} m², overlap {(in_o & in_m).sum() * area:.2f} m²")
    print(f"wrote {a.out}")
    return 0


def _fmt(rs) -> str:
    return " ∪ ".join(f"[{x:.2f}, {y:.2f}] m" for x, y in rs.intervals) if not rs.empty else "empty"


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main(sys.argv[1:]))
