"""`capm-field detect-replay RUN.mcap [--json FILE]`: the images of a run, through today's detector.

Every `/detection` of the run log whose image was stored is done again: the image that preceded
it (`/camera/image`, JPEG), the camera pose from the `/tf` tree at that moment (field → … →
camera), the camera from `/camera/calibration` (K, D) and the target's TROI (`/plan` or
`/regions`) give the same ROI the executive built (`executive.roi_for`, the TROI × ROI_MARGIN).
The rebuilt ROI is checked against the one the log holds (`Detection.roi_rim`): a run whose
geometry cannot be rebuilt says so instead of comparing answers on another region.

Per detection: the logged answer, the replayed one and how far it moved (px); on a bench run,
both answers' ground errors against `/truth/mpoi` and the count over the wrong-centre line
(`sim_bench.perception_bench.WRONG_MM`). A JPEG log (the default) holds not the frame the
detector saw but its compressed copy, and answers move with sub-level changes of the image
(docs/perception.md §4); a log with `output.image_format: png` replays exactly.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from capm_field.camera import PinholeCamera
from capm_field.cli_args import path as cli_path
from capm_field.detect_cli import check_pixels
from capm_field.detector import detect_centre
from capm_field.errors import UserError, check_output, terminal_safe, write_output

from .executive import roi_for
from .runlog import SCHEMAS, TOPICS
from .runlog_read import ReadReport, iter_run
from .runlog_schema import foreign_problem

RIM_TOL_PX = 0.5  # rebuilt ROI rim against the logged one: more than this and the geometry is not the run's
CAMERA = "camera"
FIELD = "field"


@dataclass
class Replayed:
    """One detection of the run and its replay."""

    target_id: str
    t_ns: int
    logged_pixel: tuple[float, float] | None
    logged_reason: str | None
    logged_mpoi: tuple[float, float] | None
    pixel: tuple[float, float] | None = None
    reason: str | None = None
    confidence: float = 0.0
    mpoi: tuple[float, float] | None = None
    moved_px: float | None = None
    rim_px: float | None = None  # largest distance of the rebuilt ROI rim from the logged one
    truth: tuple[float, float] | None = None
    error: str | None = None  # why this detection could not be replayed

    def err_mm(self, which: str) -> float | None:
        p = self.logged_mpoi if which == "logged" else self.mpoi
        ok = (self.logged_reason if which == "logged" else self.reason) is None
        if p is None or self.truth is None or not ok:
            return None
        return 1000.0 * math.dist(p, self.truth)


def _matrix(tr: Any) -> np.ndarray:
    """4×4 of a foxglove FrameTransform (translation, quaternion x, y, z, w)."""
    q = [tr.rotation.x, tr.rotation.y, tr.rotation.z, tr.rotation.w]
    if not np.all(np.isfinite(q)):
        raise ValueError(f"transform {tr.parent_frame_id} → {tr.child_frame_id}: no rotation")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(q).as_matrix()  # (normalises; a zero quaternion is a ValueError)
    T[:3, 3] = [tr.translation.x, tr.translation.y, tr.translation.z]
    return T


def camera_pose(tree: dict[str, tuple[str, np.ndarray]]) -> np.ndarray:
    """T_field_camera from {child: (parent, T_parent_child)}; raises ValueError if no chain."""
    T, frame, seen = np.eye(4), CAMERA, set()
    while frame != FIELD:
        if frame in seen or frame not in tree:
            raise ValueError(f"no transform chain from {FIELD} to {CAMERA} (stops at {frame!r})")
        seen.add(frame)
        parent, Tpc = tree[frame]
        T = Tpc @ T
        frame = parent
    return T


def _camera(cal: Any) -> PinholeCamera:
    K = np.asarray(cal.K, float).reshape(3, 3)
    D = np.asarray(cal.D, float)
    if len(D) == 5 and D[4] == 0.0:
        D = D[:4]  # (the log pads 4 coefficients with k3 = 0; the same lens)
    if not D.any():
        D = np.zeros(0)
    return PinholeCamera(int(cal.width), int(cal.height), K, D)


def replay(path: Path, progress: bool = True) -> tuple[list[Replayed], ReadReport]:
    report = ReadReport()
    topics = {TOPICS[k] for k in ("tf", "image", "calibration", "plan", "regions", "detection", "truth_mpoi")}
    tree: dict[str, tuple[str, np.ndarray]] = {}
    cal = None
    trois: dict[str, tuple[float, float, float]] = {}
    truth: dict[str, tuple[float, float]] = {}
    image: bytes | None = None
    out: list[Replayed] = []
    checked: dict[Any, str | None] = {}
    for m in iter_run(path, topics, report):
        msg = m.data
        why = foreign_problem(m.schema, msg, SCHEMAS[m.topic], checked)
        if why:
            report.skip(m.topic, why, m.record)
            if m.topic == TOPICS["image"]:
                image = None  # the next detection's image is not the one before this
            continue
        if m.topic == TOPICS["tf"]:
            try:
                tree = {t.child_frame_id: (t.parent_frame_id, _matrix(t)) for t in msg.transforms}
            except ValueError:
                tree = {}
            except (AttributeError, TypeError) as e:  # a FrameTransforms with other fields (Foxglove's: by name only)
                report.skip(m.topic, f"{SCHEMAS[m.topic]} with other fields: {type(e).__name__}: {e}", m.record)
                tree = {}
        elif m.topic == TOPICS["calibration"]:
            cal = msg
        elif m.topic in (TOPICS["plan"], TOPICS["regions"]):
            if msg.HasField("troi"):
                trois[msg.target_id or msg.troi.id] = (msg.troi.x, msg.troi.y, msg.troi.r)
        elif m.topic == TOPICS["truth_mpoi"]:
            truth[msg.target_id] = (msg.mpoi.x, msg.mpoi.y)
        elif m.topic == TOPICS["image"]:
            try:
                image = bytes(msg.data)
            except (AttributeError, TypeError) as e:  # a CompressedImage with other fields
                report.skip(m.topic, f"{SCHEMAS[m.topic]} with other fields: {type(e).__name__}: {e}", m.record)
                image = None
        elif m.topic == TOPICS["detection"] and msg.reason != "fault_injected":
            r = Replayed(
                msg.target_id, m.log_time,
                (msg.pixel.x, msg.pixel.y) if msg.HasField("pixel") else None,
                msg.reason or None,
                (msg.mpoi_field.x, msg.mpoi_field.y) if msg.HasField("mpoi_field") else None,
            )
            _replay_one(r, msg, image, cal, tree, trois)
            out.append(r)
            if progress:
                print(_line(r), flush=True)
    for r in out:
        r.truth = truth.get(r.target_id)
    return out, report


def _replay_one(r: Replayed, msg: Any, image: bytes | None, cal: Any, tree: dict, trois: dict) -> None:
    if image is None:
        r.error = "no image stored before it"
        return
    if cal is None or r.target_id not in trois:
        r.error = "no camera calibration" if cal is None else "its TROI is not in the log"
        return
    if not image:
        r.error = "its image is empty"
        return
    data = np.frombuffer(image, np.uint8)
    want = (int(cal.width), int(cal.height))  # the ROI is in the calibration's pixels
    try:  # the size from the header first: a log of a few kB can declare a 30 000 × 30 000 px PNG
        declared = check_pixels(data)
        if declared is not None and declared != want:
            r.error = f"its image is {declared[0]} × {declared[1]} px, the calibration's camera {want[0]} × {want[1]}"
            return
        img = cv2.imdecode(data, cv2.IMREAD_COLOR)
    except ValueError as e:
        r.error = f"its image is not a camera frame: {e}"
        return
    except cv2.error as e:  # e.g. over OpenCV's own pixel limit, or out of memory
        r.error = f"its image does not decode: {str(e).strip().splitlines()[-1][:120]}"
        return
    if img is None:
        r.error = "its image does not decode"
        return
    if (img.shape[1], img.shape[0]) != want:
        r.error = f"its image is {img.shape[1]} × {img.shape[0]} px, the calibration's camera {want[0]} × {want[1]}"
        return
    try:
        cam = _camera(cal)
        T = camera_pose(tree)
        x, y, rad = trois[r.target_id]
        roi = roi_for(cam, T, (x, y), rad)
    except Exception as e:  # noqa: BLE001 - a foreign or damaged log's numbers (NaN, a singular K)
        r.error = f"cannot rebuild its ROI: {type(e).__name__}: {' '.join(str(e).split())[:120]}"
        return
    logged_rim = np.array([(p.x, p.y) for p in getattr(msg, "roi_rim", ())], float)
    if len(logged_rim) >= 3:
        rim = roi.rim(len(logged_rim))
        r.rim_px = float(np.max(np.linalg.norm(rim - logged_rim, axis=1)))
        if not r.rim_px <= RIM_TOL_PX:
            r.error = f"the rebuilt ROI is {r.rim_px:.1f} px off the logged one"
            return
    det = detect_centre(img, roi)  # (never raises: a bad frame is a reason)
    r.pixel = None if det.pixel is None else (float(det.pixel[0]), float(det.pixel[1]))
    r.reason, r.confidence = det.reason, float(det.confidence)
    if r.pixel is not None and r.reason is None:
        g = cam.pixel_to_ground(T, np.array([r.pixel]))[0]
        r.mpoi = (float(g[0]), float(g[1])) if np.all(np.isfinite(g)) else None
    if r.pixel is not None and r.logged_pixel is not None:
        r.moved_px = math.dist(r.pixel, r.logged_pixel)


def _answer(pixel, reason) -> str:
    if pixel is not None and reason is None:
        return f"({pixel[0]:.1f}, {pixel[1]:.1f})"
    return terminal_safe(reason) if reason else "none"  # (a logged reason is the log's text)


def _line(r: Replayed) -> str:
    """One detection's line; its id as read from the log, escaped (a log is someone else's text)."""
    tid = terminal_safe(r.target_id)
    if r.error is not None:
        return f"{tid}: not replayed: {terminal_safe(r.error)}"
    moved = f", moved {r.moved_px:.1f} px" if r.moved_px is not None else ""
    return f"{tid}: logged {_answer(r.logged_pixel, r.logged_reason)}, now {_answer(r.pixel, r.reason)}{moved}"


def summary(rows: list[Replayed]) -> dict[str, Any]:
    from sim_bench.perception_bench import WRONG_MM  # the bench's wrong-centre line (imported when run, as run_cli does)

    done = [r for r in rows if r.error is None]
    found = lambda p, why: p is not None and why is None  # noqa: E731
    s: dict[str, Any] = {
        "detections": len(rows),
        "replayed": len(done),
        "not_replayed": len(rows) - len(done),
        "found_logged": sum(found(r.logged_pixel, r.logged_reason) for r in done),
        "found_now": sum(found(r.pixel, r.reason) for r in done),
        "moved_over_1px": sum(r.moved_px is not None and r.moved_px > 1.0 for r in done),
        "max_rim_px": max((r.rim_px for r in done if r.rim_px is not None), default=None),
        "wrong_mm": WRONG_MM,
    }
    for which in ("logged", "now"):
        e = [x for r in done if (x := r.err_mm(which)) is not None and math.isfinite(x)]  # (NaN: a damaged log's)
        s[f"error_mm_{which}"] = {"n": len(e), "median": float(np.median(e)) if e else None,
                                  "wrong": sum(x > WRONG_MM for x in e)}
    return s


def _finite(v: Any) -> Any:
    """`v` with NaN and ±inf (a damaged or foreign log's numbers) as None: standard JSON has no
    NaN, and other readers refuse the `NaN` Python would write."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_finite(x) for x in v]
    return v


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="capm-field detect-replay",
                                 description="Run a run log's images through today's detector and compare with the logged answers.")
    ap.add_argument("run", type=cli_path, metavar="RUN.mcap", help="a run log (or its run directory)")
    ap.add_argument("--json", metavar="FILE", help="write every detection and the summary to FILE")
    ap.add_argument("--quiet", action="store_true", help="only the summary")
    try:
        a = ap.parse_args(argv)
    except SystemExit as e:
        return 0 if e.code == 0 else 2
    path = Path(a.run)
    if path.is_dir():
        path = path / "run.mcap"
    check_output(a.json, "--json", inputs=[path])
    rows, report = replay(path, progress=not a.quiet)
    notes = report.notes(path)  # a truncated or damaged log: said, not hidden behind the figures
    for note in notes:
        print(f"capm-field detect-replay: note: {terminal_safe(note)}", file=sys.stderr)
    if not rows:
        damaged = " in what could be read" if notes else ""
        raise UserError(f"{path}: no detections to replay{damaged} (only fault-injected ones, or none)")
    if all(r.error == "no image stored before it" for r in rows):
        raise UserError(f"{path}: the run stored no images (output.images: false)")
    if all(r.error is not None for r in rows):
        raise UserError(f"{path}: none of its {len(rows)} detections could be replayed ({rows[0].target_id}: {rows[0].error})"
                        + ("; the log is damaged (notes above)" if notes else ""))
    s = summary(rows)
    print(f"{s['replayed']} of {s['detections']} detections replayed: found {s['found_logged']} logged, {s['found_now']} now; "
          f"{s['moved_over_1px']} answers moved > 1 px")
    for which in ("logged", "now"):
        e = s[f"error_mm_{which}"]
        if e["n"]:
            print(f"  against the bench truth, {which:<6}: median {e['median']:.1f} mm, {e['wrong']} of {e['n']} over {s['wrong_mm']:.0f} mm")
    if a.json:
        doc = {"run": str(path), "summary": s, "log_notes": notes, "detections": [r.__dict__ for r in rows]}
        write_output(a.json, json.dumps(_finite(doc), indent=2, allow_nan=False), "--json")
    return 0
