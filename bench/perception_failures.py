"""Failures of `capm-field bench-perception`: re-run the bench cases (same seeds), list per-case
results and save side-by-side PNGs of the failing ones.

    .venv/bin/python bench/perception_failures.py --scenes 300 --seed 0 --out /tmp/pf [--jobs 2]
    .venv/bin/python bench/perception_failures.py --scenes 300 --seeds 0-7 --jobs 2 --save none   (pooled)

Rendered views are cached as lossless PNGs under --cache (default /tmp/pf_cache/<seed>) so the
detector can be re-evaluated quickly. For each failure (miss, false plant on bare soil, or centre
> 30 mm off) a PNG is written: left the ROI window with the ROI ellipse (yellow), the true centre
(green cross) and the estimate (red cross); right the same window's vegetation mask as the
detector saw it (grey: all components, white: the chosen plant) with the same marks.
Prints a per-kind summary and writes cases.json (one row per case).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from capm_field.camera import PinholeCamera
from capm_field.config import CameraConfig, TaskConfig
from capm_field.detector import ground_centre, roi_from_troi
from capm_field.roi import Roi
import capm_field.detector as _det

DETECT = _det.detect_centre
ALT_TAKES_ROI = False  # set by _load_detector


def _load_detector(path: str) -> None:
    """Use detect_centre from another detector file (A/B comparisons with an older version)."""
    import importlib.util

    global DETECT, ALT_TAKES_ROI
    spec = importlib.util.spec_from_file_location("capm_field._detector_alt", path)
    mod = importlib.util.module_from_spec(spec)
    mod.__package__ = "capm_field"
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    DETECT = mod.detect_centre
    # a file importing today's capm_field.roi is given the same Roi as today's detector (its ground
    # scale weights the plant choice); one with a Roi class of its own gets the bare conic
    ALT_TAKES_ROI = getattr(mod, "Roi", None) is Roi
from sim_bench.perception_bench import WRONG_MM, bare_cases, make_case

CAM = PinholeCamera.from_config(CameraConfig())


def _case_image(seed: int, i: int, bare: bool, cache: Path):
    delta = TaskConfig().delta
    case = make_case(seed, i, CAM, delta, bare)
    if case is None:
        return None, None
    f = cache / f"{i:05d}.png"
    img = cv2.imread(str(f)) if f.exists() else None
    if img is None:
        img = case.scene.render(case.T, CAM)
        cv2.imwrite(str(f), img, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    return case, img


def evaluate(args) -> dict | None:
    seed, i, bare, cache, out, save, alt, jpeg, j444 = args
    cv2.setNumThreads(1)
    if alt and DETECT is _det.detect_centre:
        _load_detector(alt)
    case, img = _case_image(seed, i, bare, cache)
    if case is None:
        return None
    if jpeg:  # the frame as a camera streaming JPEG (or a run log, docs/log.md) would deliver it
        params = [cv2.IMWRITE_JPEG_QUALITY, jpeg] + ([cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444] if j444 else [])
        img = cv2.imdecode(cv2.imencode(".jpg", img, params)[1], cv2.IMREAD_COLOR)
    roi = roi_from_troi(CAM, case.T, case.troi_centre, case.troi_radius)
    dbg: dict = {}
    t0 = time.perf_counter()
    if DETECT is _det.detect_centre:
        det = DETECT(img, roi, debug=dbg)
    else:  # another detector file: maybe its own Roi class (then the conic), maybe no debug argument
        arg = roi if ALT_TAKES_ROI else roi.conic
        try:
            det = DETECT(img, arg, debug=dbg)
        except TypeError:
            det = DETECT(img, arg)
    lat = time.perf_counter() - t0
    row = {"i": i, "kind": case.kind, "reason": det.reason, "conf": det.confidence, "lat_ms": lat * 1000,
           "pixel": det.pixel, "method": dbg.get("method"), "roundness": dbg.get("roundness")}
    truth_px = None
    if case.kind != "bare":
        w = case.scene.weeds[0]
        truth_px = CAM.ground_to_pixel(case.T, w.centre[None])[0]
        row["truth_px"] = [float(truth_px[0]), float(truth_px[1])]
        row["size_mm"] = float(w.plant.extent * 1000)
        g = ground_centre(CAM, case.T, det)
        row["err_mm"] = float(np.linalg.norm(g - w.centre) * 1000) if (g is not None and det.reason is None) else None
        fail = det.reason is not None or row["err_mm"] is None or row["err_mm"] > WRONG_MM
    else:
        fail = det.reason != "no_plant"
    row["fail"] = bool(fail)
    if save and (fail or save == "all"):
        _save(out / f"{'FAIL' if fail else 'ok'}_{case.kind}_{i:05d}.png", img, roi, truth_px, det, dbg, row)
    return row


def _save(path: Path, img, roi, truth_px, det, dbg, row) -> None:
    (cu, cv_), (ew, eh), ang = roi.ellipse()
    r = 0.6 * max(ew, eh) * 1.15
    x0, y0 = max(int(cu - r), 0), max(int(cv_ - r), 0)
    x1, y1 = min(int(cu + r), img.shape[1]), min(int(cv_ + r), img.shape[0])
    left = img[y0:y1, x0:x1].copy()
    right = np.zeros_like(left)
    m = dbg.get("mask_full")
    if m is not None:
        right[m[y0:y1, x0:x1] == 1] = (110, 110, 110)
        right[m[y0:y1, x0:x1] == 2] = (255, 255, 255)
    k = min(1.0, 700 / max(left.shape[:2]))
    k = max(k, 400 / max(left.shape[:2]))
    left = cv2.resize(left, None, fx=k, fy=k, interpolation=cv2.INTER_AREA if k < 1 else cv2.INTER_LINEAR)
    right = cv2.resize(right, (left.shape[1], left.shape[0]), interpolation=cv2.INTER_NEAREST)

    def P(p):
        return (int(round((p[0] - x0) * k)), int(round((p[1] - y0) * k)))

    for im in (left, right):
        cv2.ellipse(im, P((cu, cv_)), (int(ew / 2 * k), int(eh / 2 * k)), ang, 0, 360, (0, 220, 255), 1)
        if truth_px is not None:
            cv2.drawMarker(im, P(truth_px), (0, 255, 0), cv2.MARKER_CROSS, 18, 2)
        if det.pixel is not None:
            cv2.drawMarker(im, P(det.pixel), (0, 0, 255), cv2.MARKER_TILTED_CROSS, 18, 2)
        for c in dbg.get("candidates_full", []):
            cv2.circle(im, P(c), 5, (255, 0, 255), 1)
    txt = f"{row['kind']} #{row['i']} {det.reason} err={row.get('err_mm')} conf={det.confidence:.2f} m={row.get('method')}"
    side = np.concatenate([left, right, _zoom(img, m, truth_px, det, left.shape[0])], axis=1)
    cv2.putText(side, txt, (5, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3)
    cv2.putText(side, txt, (5, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1)
    cv2.imwrite(str(path), side)


def _zoom(img, m, truth_px, det, h):
    """Full-resolution close-up (h × h) of the chosen plant's box, truth and estimate marked."""
    pts = []
    if m is not None and np.any(m == 2):
        ys, xs = np.nonzero(m == 2)
        pts += [(xs.min(), ys.min()), (xs.max(), ys.max())]
    for p in (truth_px, det.pixel):
        if p is not None:
            pts.append(tuple(p))
    if not pts:
        return np.zeros((h, h, 3), np.uint8)
    P = np.array(pts, float)
    c = (P.min(0) + P.max(0)) / 2
    r = max(40.0, 0.6 * float((P.max(0) - P.min(0)).max()))
    x0, y0 = int(c[0] - r), int(c[1] - r)
    n = int(2 * r)
    pad = cv2.copyMakeBorder(img, n, n, n, n, cv2.BORDER_CONSTANT)
    z = cv2.resize(pad[y0 + n:y0 + 2 * n, x0 + n:x0 + 2 * n], (h, h), interpolation=cv2.INTER_NEAREST)
    k = h / n

    def Q(p):
        return (int(round((p[0] - x0 + 0.5) * k)), int(round((p[1] - y0 + 0.5) * k)))

    if truth_px is not None:
        cv2.drawMarker(z, Q(truth_px), (0, 255, 0), cv2.MARKER_CROSS, 22, 2)
    if det.pixel is not None:
        cv2.drawMarker(z, Q(det.pixel), (0, 0, 255), cv2.MARKER_TILTED_CROSS, 22, 2)
    return z


def _seeds(text: str) -> list[int]:
    """'0-7' or '0,2,5' (or a mix: '0-3,6') → the seeds."""
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.strip().partition("-")
        out += list(range(int(lo), int(hi) + 1)) if hi else [int(lo)]
    return out


def cache_dir(cache: str | None, seed: int, several: bool) -> Path:
    """The render cache of `seed` (made if missing): /tmp/pf_cache/<seed> by default, `cache` with
    '{seed}' replaced, or, for several seeds sharing a `cache` without '{seed}', its subdirectory
    <seed> (views are named by case index only)."""
    if cache is None:
        d = Path(f"/tmp/pf_cache/{seed}")
    elif "{seed}" in cache or not several:
        d = Path(cache.format(seed=seed))
    else:
        d = Path(cache) / str(seed)
    d.mkdir(parents=True, exist_ok=True)
    return d


def _run_seed(a, seed: int, out: Path) -> list[dict]:
    """The bench cases of one seed evaluated (rendered views cached), their rows written to
    out/cases.json and failing frames saved as PNGs there (per --save)."""
    out.mkdir(parents=True, exist_ok=True)
    for f in out.glob("*.png"):
        f.unlink()
    cache = cache_dir(a.cache, seed, several=a.seeds is not None)
    bare_idx = bare_cases(seed, a.scenes, a.bare_share)
    idx = range(a.scenes) if a.only is None else [int(s) for s in a.only.split(",")]
    save = None if a.save == "none" else a.save
    jobs = [(seed, i, i in bare_idx, cache, out, save, a.detector, a.jpeg, a.jpeg_444) for i in idx]
    if a.jobs > 1:
        with ProcessPoolExecutor(a.jobs) as ex:
            rows = [r for r in ex.map(evaluate, jobs, chunksize=4) if r is not None]
    else:
        rows = [r for r in map(evaluate, jobs) if r is not None]
    (out / "cases.json").write_text(json.dumps(rows, indent=1))
    return rows


def _summary(rows: list[dict], kinds: bool = True) -> None:
    weeds = [r for r in rows if r["kind"] != "bare"]
    bare = [r for r in rows if r["kind"] == "bare"]
    errs = [r["err_mm"] for r in weeds if r["err_mm"] is not None]
    det = len(errs)
    n_wrong = sum(e > WRONG_MM for e in errs)
    print(f"weed {len(weeds)}: detected {det / max(len(weeds), 1):.1%} ({det}), wrong {n_wrong / max(len(weeds), 1):.1%} ({n_wrong}), "
          f"err median {np.median(errs) if errs else float('nan'):.2f} p90 {np.percentile(errs, 90) if errs else float('nan'):.2f} max {max(errs, default=float('nan')):.0f} mm; "
          f"bare no_plant {sum(r['reason'] == 'no_plant' for r in bare)}/{len(bare)}; "
          f"latency median {np.median([r['lat_ms'] for r in rows]):.1f} p90 {np.percentile([r['lat_ms'] for r in rows], 90):.1f} ms")
    if not kinds:
        return
    for k in sorted({r["kind"] for r in weeds}):
        rk = [r for r in weeds if r["kind"] == k]
        ek = [r["err_mm"] for r in rk if r["err_mm"] is not None]
        reasons = {}
        for r in rk:
            if r["reason"]:
                reasons[r["reason"]] = reasons.get(r["reason"], 0) + 1
        med, p90 = (np.median(ek), np.percentile(ek, 90)) if ek else (float("nan"), float("nan"))  # --only: maybe none found
        print(f"  {k:<9} n {len(rk):>3} det {len(ek) / len(rk):6.1%} wrong {sum(e > WRONG_MM for e in ek):>2} "
              f"median {med:5.2f} p90 {p90:6.2f} mm  misses {reasons}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--seeds", default=None,
                    help="several seeds, e.g. 0-7 or 0,2,5: each seed's cases under --out/seed_<S>, its summary, "
                         "then the pooled one (the figure docs/perception.md quotes for seeds 0–7)")
    ap.add_argument("--bare-share", type=float, default=0.15)
    ap.add_argument("--out", default="/tmp/pf")
    ap.add_argument("--cache", default=None, help="rendered views' directory; '{seed}' in it is replaced; with --seeds "
                                                  "and no '{seed}', one subdirectory per seed (default /tmp/pf_cache/<seed>)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--save", choices=["fail", "all", "none"], default="fail")
    ap.add_argument("--only", default=None, help="comma-separated case indices")
    ap.add_argument("--detector", default=None, help="path of another detector.py to evaluate instead (A/B)")
    ap.add_argument("--jpeg", type=int, default=0, metavar="Q", help="detect on each frame JPEG-encoded at quality Q (1-100; 0: the lossless render)")
    ap.add_argument("--jpeg-444", action="store_true", help="with --jpeg: full-resolution colour (OpenCV's default halves it, 4:2:0)")
    a = ap.parse_args(argv)
    if not 0 <= a.jpeg <= 100:
        ap.error("--jpeg: a quality in 1..100, or 0 for none")
    if a.seeds is None:
        rows = _run_seed(a, a.seed, Path(a.out))
        _summary(rows)
        print("failing:", ",".join(str(r["i"]) for r in rows if r["fail"]))
        return 0
    pooled: list[dict] = []
    for seed in _seeds(a.seeds):
        rows = _run_seed(a, seed, Path(a.out) / f"seed_{seed}")
        print(f"seed {seed}: ", end="")
        _summary(rows, kinds=False)
        pooled += rows
    print("pooled:", end=" ")
    _summary(pooled)
    return 0


if __name__ == "__main__":
    sys.exit(main())
