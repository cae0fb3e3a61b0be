"""`capm-field bench-perception`: weed-centre detector accuracy and latency on rendered scenes.

Each scene holds one weed (mixed kinds, sizes, clutter, crop rows, cast shadows, lighting) or, for
a share of scenes, bare soil. The camera pose is sampled the way the arm takes close-ups (height
0.5–1.5 m, tilt 0–35° from nadir, any azimuth and roll) and kept only if it satisfies NSV for the
TROI disc: `disc_view` coverage and area ratio h ≥ δ (TaskConfig.delta). The detector gets the
projected TROI as its ROI; its pixel is mapped to the ground with H⁻¹ and compared with the
weed's known biological centre.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass

import cv2
import numpy as np
from pydantic import ValidationError

from capm_field.cli_args import count
from capm_field.cli_args import seed as cli_seed
from capm_field.camera import PinholeCamera
from capm_field.config import CameraConfig, TaskConfig
from capm_field.detector import detect_centre, ground_centre, roi_from_troi
from capm_field.errors import UserError, check_output, shown, write_output

from .field_scene import FieldScene
from .plants import WEED_KINDS

WRONG_MM = 30.0
SIZES = {"rosette": (0.04, 0.14), "seedling": (0.012, 0.04), "grass": (0.05, 0.16), "clover": (0.04, 0.10)}


@dataclass
class Case:
    scene: FieldScene
    T: np.ndarray
    troi_centre: np.ndarray
    troi_radius: float
    kind: str  # weed kind or "bare"


def sample_nsv_pose(
    rng: np.random.Generator, camera: PinholeCamera, centre: np.ndarray, radius: float, delta: float, tries: int = 400
) -> np.ndarray | None:
    """A camera pose an arm could take (h 0.5–1.5 m, tilt ≤ 35°, any azimuth/roll) satisfying NSV."""
    for _ in range(tries):
        h = rng.uniform(0.5, 1.5)
        tilt = math.radians(rng.uniform(0, 35))
        az = rng.uniform(0, 2 * math.pi)
        roll = rng.uniform(0, 2 * math.pi)
        aim = np.r_[centre + rng.normal(0, 0.15 * radius, 2), 0.0]
        z = np.array([math.sin(tilt) * math.cos(az), math.sin(tilt) * math.sin(az), -math.cos(tilt)])
        pos = aim - z * (h / math.cos(tilt))
        T = pose_from_axis(pos, z, roll)
        cov, ratio = camera.disc_view(T, centre, radius)
        if bool(cov) and float(ratio) >= delta:
            return T
    return None


def pose_from_axis(pos: np.ndarray, z: np.ndarray, roll: float) -> np.ndarray:
    """T_field_cam with optical axis z at pos, rolled by `roll` about it."""
    z = z / np.linalg.norm(z)
    ref = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(ref, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = math.cos(roll), math.sin(roll)
    T = np.eye(4)
    T[:3, :3] = np.c_[c * x + s * y, -s * x + c * y, z]
    T[:3, 3] = pos
    return T


def bare_cases(seed: int, scenes: int, bare_share: float) -> set[int]:
    """Indices of a seed's bench cases that are bare soil (round(scenes × bare_share) of them, drawn by seed)."""
    n_bare = int(round(scenes * bare_share))
    return set(np.random.default_rng(seed).choice(scenes, n_bare, replace=False).tolist()) if n_bare else set()


def make_case(seed: int, index: int, camera: PinholeCamera, delta: float, bare: bool) -> Case | None:
    """One bench case (scene + NSV pose); None if no NSV pose was found."""
    rng = np.random.default_rng([seed, index])
    Xw = rng.uniform(-1.0, 1.0, 2)
    r_w = rng.uniform(0.2, 0.3)
    kind = "bare" if bare else WEED_KINDS[index % len(WEED_KINDS)]
    common = dict(
        area=(Xw[0] - 1.0, Xw[1] - 1.0, Xw[0] + 1.0, Xw[1] + 1.0),
        crop_rows=bool(rng.random() < 0.2),
        distractors_per_m2=float(rng.choice([0.0, 5.0, 20.0])),
        shadows=int(rng.integers(0, 3)),
    )
    sseed = int(rng.integers(2**31))
    if bare:
        scene = FieldScene.bare(sseed, **{**common, "distractors_per_m2": 0.0}, clear_zones=[(Xw, r_w)])
    else:
        size = float(np.exp(rng.uniform(*np.log(SIZES[kind]))))
        room = max(r_w - 1.1 * size, 0.0)
        off = rng.uniform(0, room) * np.array([math.cos(a := rng.uniform(0, 2 * math.pi)), math.sin(a)])
        w = dict(x=Xw[0] + off[0], y=Xw[1] + off[1], kind=kind, size=size, troi_centre=Xw, troi_radius=r_w)
        scene = FieldScene.generate(sseed, weeds=[w], **common)
    T = sample_nsv_pose(rng, camera, Xw, r_w, delta)
    return None if T is None else Case(scene, T, Xw, r_w, kind)


def _stats(a: list[float]) -> dict:
    if not a:
        return {"median": None, "p90": None, "max": None, "n": 0}
    x = np.asarray(a, float)
    return {"median": float(np.median(x)), "p90": float(np.percentile(x, 90)), "max": float(x.max()), "n": len(x)}


def run(
    scenes: int, seed: int, bare_share: float, use_roi: bool = True, progress: bool = True, camera_cfg: CameraConfig | None = None
) -> dict:
    cv2.setNumThreads(1)
    camera = PinholeCamera.from_config(camera_cfg or CameraConfig())
    delta = TaskConfig().delta
    bare_idx = bare_cases(seed, scenes, bare_share)
    err_px, err_mm, lat, rend = [], [], [], []
    per_kind: dict = {}
    n_weed = n_det = n_wrong = n_bare_ok = n_bare_total = skipped = 0
    reasons: dict = {}
    it = range(scenes)
    if progress:
        from tqdm import tqdm

        it = tqdm(it, desc="bench-perception", unit="scene")
    for i in it:
        case = make_case(seed, i, camera, delta, i in bare_idx)
        if case is None:
            skipped += 1
            continue
        t0 = time.perf_counter()
        img = case.scene.render(case.T, camera)
        rend.append(time.perf_counter() - t0)
        roi = roi_from_troi(camera, case.T, case.troi_centre, case.troi_radius) if use_roi else None
        t0 = time.perf_counter()
        det = detect_centre(img, roi)
        lat.append(time.perf_counter() - t0)
        reasons[str(det.reason)] = reasons.get(str(det.reason), 0) + 1
        if case.kind == "bare":
            n_bare_total += 1
            n_bare_ok += det.reason == "no_plant"
            continue
        n_weed += 1
        k = per_kind.setdefault(case.kind, {"n": 0, "detected": 0, "wrong": 0, "err_mm": []})
        k["n"] += 1
        if det.reason is not None or det.pixel is None:
            continue
        n_det += 1
        k["detected"] += 1
        weed = case.scene.weeds[0]
        true_px = camera.ground_to_pixel(case.T, weed.centre[None])[0]
        g = ground_centre(camera, case.T, det)
        e_mm = float(np.linalg.norm(g - weed.centre) * 1000) if g is not None else float("inf")
        err_px.append(float(np.linalg.norm(np.asarray(det.pixel) - true_px)))
        err_mm.append(e_mm)
        k["err_mm"].append(e_mm)
        if e_mm > WRONG_MM:
            n_wrong += 1
            k["wrong"] += 1
    return {
        "scenes": scenes,
        "seed": seed,
        "roi": use_roi,
        "skipped_no_nsv_pose": skipped,
        "weed_scenes": n_weed,
        "bare_scenes": n_bare_total,
        "detection_rate": n_det / n_weed if n_weed else None,
        "wrong_centre_rate": n_wrong / n_weed if n_weed else None,
        "wrong_centre_threshold_mm": WRONG_MM,
        "centre_error_px": _stats(err_px),
        "centre_error_mm": _stats(err_mm),
        "no_plant_rate_bare": n_bare_ok / n_bare_total if n_bare_total else None,
        "latency_ms": {k: (v * 1000 if isinstance(v, float) else v) for k, v in _stats(lat).items()},
        "render_ms": {k: (v * 1000 if isinstance(v, float) else v) for k, v in _stats(rend).items()},
        "reasons": reasons,
        "per_kind": {
            k: {"n": v["n"], "detection_rate": v["detected"] / v["n"], "wrong": v["wrong"], "err_mm": _stats(v["err_mm"])}
            for k, v in sorted(per_kind.items())
        },
        "image": [camera.width, camera.height],
        "distortion": [float(v) for v in np.asarray(camera.dist).ravel()],
        "threads": 1,
    }


def _fmt(d: dict, unit: str) -> str:
    if not d["n"]:
        return "n/a"
    return f"median {d['median']:.2f} {unit}, p90 {d['p90']:.2f} {unit}, max {d['max']:.2f} {unit}"


def _camera_config(text: str) -> CameraConfig:
    """The bench camera, with `--distortion` coefficients when given (checked as a mission's are)."""
    if not text.strip():
        return CameraConfig()
    try:
        dist = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise UserError(f"--distortion: give comma-separated numbers (k1,k2,p1,p2[,k3...]), got {shown(text)}") from None
    try:
        return CameraConfig(distortion=dist)
    except ValidationError as e:
        raise UserError(f"--distortion: {e.errors()[0]['msg'].removeprefix('Value error, ')}") from None


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="capm-field bench-perception", description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=count(1, 100_000), default=300, help="number of scenes (default 300)")
    ap.add_argument("--seed", type=cli_seed, default=0)
    ap.add_argument("--bare-share", type=float, default=0.15, help="share of bare-soil scenes (default 0.15)")
    ap.add_argument("--no-roi", action="store_true", help="search the whole image instead of the projected TROI")
    ap.add_argument("--json", metavar="FILE", help="write the figures to FILE")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    ap.add_argument(
        "--distortion", metavar="K1,K2,P1,P2[,K3[,K4,K5,K6]]", default="",
        help="render through a lens with this distortion (OpenCV's order) and map the detections back through it",
    )
    try:
        a = ap.parse_args(argv)
    except SystemExit as e:  # argparse printed its usage and error line already
        return 0 if e.code == 0 else 2
    check_output(a.json, "--json")
    camera_cfg = _camera_config(a.distortion)
    if not 0.0 <= a.bare_share <= 1.0:
        raise UserError(f"--bare-share must be in [0, 1], got {a.bare_share}")
    r = run(a.scenes, a.seed, a.bare_share, not a.no_roi, progress=not a.quiet, camera_cfg=camera_cfg)
    if r["weed_scenes"] + r["bare_scenes"] == 0:  # (a lens so strong that no pose sees a TROI whole)
        raise UserError(f"no NSV pose in any of the {r['scenes']} scenes for this camera"
                        f"{' (--distortion ' + shown(a.distortion) + ')' if a.distortion.strip() else ''}: nothing measured")
    pct = lambda v: "n/a" if v is None else f"{100 * v:.1f} %"  # noqa: E731
    print(f"scenes {r['scenes']} (weed {r['weed_scenes']}, bare {r['bare_scenes']}, no NSV pose {r['skipped_no_nsv_pose']}), seed {r['seed']}, roi {r['roi']}")
    print(f"detection rate        {pct(r['detection_rate'])}")
    print(f"wrong centre (>{WRONG_MM:.0f} mm)  {pct(r['wrong_centre_rate'])}")
    print(f"centre error (ground) {_fmt(r['centre_error_mm'], 'mm')}")
    print(f"centre error (image)  {_fmt(r['centre_error_px'], 'px')}")
    print(f"no plant on bare soil {pct(r['no_plant_rate_bare'])}")
    print(f"latency per frame     median {r['latency_ms']['median']:.1f} ms, p90 {r['latency_ms']['p90']:.1f} ms (1 thread, {r['image'][0]}x{r['image'][1]})")
    if r["distortion"]:
        print(f"lens distortion       {', '.join(f'{v:g}' for v in r['distortion'])}")
    for k, v in r["per_kind"].items():
        print(f"  {k:<9} n {v['n']:>3}  detected {pct(v['detection_rate']):>7}  wrong {v['wrong']:>2}  error {_fmt(v['err_mm'], 'mm')}")
    if a.json:
        write_output(a.json, json.dumps(r, indent=2), "--json")
    return 0
