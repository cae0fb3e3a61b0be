"""`capm-field detect IMAGE|DIR ... [--roi U,V,R] [--roi-mask FILE] [--json FILE] [--annotate DIR]`:
the weed-centre detector (`capm_field.detector.detect_centre`) on image files — a field photo,
a frame saved from the arm camera — without a robot, a mission or a pose.

One line per image: the centre's pixel (u, v) and its confidence, or the reason there is no
answer. Pixels are those of the image as shown (EXIF orientation applied, as `cv2.imread`
does; pixel centres at integer coordinates). Every image is read as 8-bit BGR (grey and 16-bit
files converted, alpha dropped). A directory stands for the image files directly in it.

A file that cannot be read or decoded is reported on its line and the rest go on; the exit
code is then 2 (bad input), else 0, whatever the detector answered. `--json` is written even
when interrupted (with `"interrupted": true`), so a long batch loses nothing already done.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from . import cli_args
from .detector import Detection, Roi, detect_centre
from .errors import UserError, check_output, same_file, shown, write_output

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp", ".jp2", ".pgm", ".ppm", ".pnm"}
MAX_FILE_BYTES = 1 << 30  # 1 GiB: far above any camera's frame; a file this big is not a photo
MAX_PIXELS = 200_000_000  # a 200 MP phone photo; decoded as 8-bit BGR that is 0.6 GB before any work
MAX_COORD = 1e7  # px: no image comes near; keeps the ROI's arithmetic finite


@dataclass
class Result:
    """One image's line: the detector's answer, or why the file gave none."""

    file: str
    width: int | None = None
    height: int | None = None
    pixel: tuple[float, float] | None = None
    confidence: float | None = None
    reason: str | None = None
    latency_ms: float | None = None
    error: str | None = None  # the file could not be read, decoded or matched to the ROI mask
    annotated: str | None = None

    def line(self) -> str:
        if self.error is not None:
            return f"{self.file}  error: {self.error}"
        size = f"{self.width}x{self.height}"
        ms = f"{self.latency_ms:.0f} ms"
        if self.reason is None and self.pixel is not None:
            return f"{self.file}  {size}  centre ({self.pixel[0]:.1f}, {self.pixel[1]:.1f}) px  confidence {self.confidence:.2f}  {ms}"
        guess = f" (best guess ({self.pixel[0]:.1f}, {self.pixel[1]:.1f}) px)" if self.pixel is not None else ""
        return f"{self.file}  {size}  no answer: {self.reason}{guess}  {ms}"

    def record(self) -> dict[str, Any]:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


def _numbers(text: str, flag: str) -> tuple[float, ...]:
    vals = cli_args.floats(text, flag)
    if not all(math.isfinite(v) and abs(v) <= MAX_COORD for v in vals):
        raise UserError(f"{flag}: numbers must be finite and within ±{MAX_COORD:g} px, got {shown(text)}")
    return vals


def parse_roi(text: str) -> Roi:
    """`U,V,R` (a circle: centre and radius, px) or `U,V,W,H,ANGLE` (an ellipse as OpenCV's
    RotatedRect: centre, full width and height in px, angle in degrees) → a Roi."""
    v = _numbers(text, "--roi")
    if len(v) == 3:
        u, vv, r = v
        if not r >= 1:
            raise UserError(f"--roi: the radius must be at least 1 px, got {r:g}")
        return Roi.from_ellipse((u, vv), (r, r))
    if len(v) == 5:
        u, vv, w, h, ang = v
        if not (w >= 2 and h >= 2):
            raise UserError(f"--roi: width and height must be at least 2 px, got {w:g} and {h:g}")
        return Roi.from_ellipse((u, vv), (w / 2, h / 2), ang)
    raise UserError(f"--roi: give U,V,R (a circle) or U,V,W,H,ANGLE (an ellipse), got {len(v)} numbers")


def image_files(paths: list[str]) -> list[tuple[str, Path | None, str | None]]:
    """(shown name, path, error) per input: a directory's image files (sorted by name, not its
    subdirectories) or the file itself; a path that is neither gives an error row."""
    out: list[tuple[str, Path | None, str | None]] = []
    for p in paths:
        path = Path(p)
        if path.is_dir():
            try:
                found = sorted(q for q in path.iterdir() if q.suffix.lower() in IMAGE_SUFFIXES and q.is_file())
            except OSError as e:
                out.append((p, None, f"cannot list the directory: {e.strerror or e}"))
                continue
            if not found:
                out.append((p, None, f"no image files ({', '.join(sorted(IMAGE_SUFFIXES))}) in this directory"))
            out += [(str(q), q, None) for q in found]
        elif path.is_file():
            out.append((p, path, None))
        elif path.exists():  # a FIFO or a device: reading it may never end
            out.append((p, None, "not a regular file"))
        else:
            out.append((p, None, "no such file or directory"))
    return out


def read_image(path: Path) -> np.ndarray:
    """8-bit BGR image from a file (EXIF orientation applied); raises ValueError with the reason."""
    if path.exists() and not path.is_file():
        raise ValueError("not a regular file")  # a FIFO or a device: reading it may never end
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise ValueError(f"{size / 2**20:.0f} MiB, over the {MAX_FILE_BYTES >> 20} MiB a frame or photo can be")
        data = np.fromfile(str(path), np.uint8)  # (not cv2.imread: its failures say nothing)
    except OSError as e:
        raise ValueError(f"cannot read it: {e.strerror or e}") from None
    check_pixels(data)
    try:
        img = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    except cv2.error as e:  # e.g. over OpenCV's pixel limit
        raise ValueError(f"OpenCV cannot decode it: {str(e).strip().splitlines()[-1][:160]}") from None
    if img is None:
        raise ValueError("not an image OpenCV can decode" if data.size else "empty file")
    return img


def check_pixels(data: np.ndarray) -> tuple[int, int] | None:
    """Refuse an image of over MAX_PIXELS from its header, before it is decoded: a PNG of a few kB
    can declare 20 000 × 20 000 px (2.5 GB in OpenCV before the detector said bad_image). Pillow
    reads the header (from the first 16 MiB); a format or layout it does not read there is left to
    OpenCV, whose own cap is 2^30 px. Past twice Pillow's MAX_IMAGE_PIXELS (~179 Mpx by default)
    Pillow refuses to open it and its error gives the pixel count; the size read counts where
    that limit is higher or off. Returns the (width, height) the header declares, None where
    Pillow could not read it."""
    import re
    import warnings

    from PIL import Image

    size = None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Pillow's DecompressionBombWarning: the size is checked here
        try:
            with Image.open(io.BytesIO(data[: 16 << 20].tobytes())) as im:
                size = (im.width, im.height)
                pixels, dims = im.width * im.height, f"{im.width} × {im.height} px"
        except Image.DecompressionBombError as e:  # over 2× Pillow's own limit (~179 Mpx)
            m = re.search(r"\((\d+) pixels\)", str(e))
            pixels, dims = (int(m[1]), f"{int(m[1]) / 1e6:.0f} Mpx") if m else (MAX_PIXELS + 1, "its size")
        except Exception:  # noqa: BLE001 - not a format Pillow reads, or a header past 16 MiB
            return None
    if pixels > MAX_PIXELS:
        raise ValueError(f"{dims}, over the {MAX_PIXELS / 1e6:.0f} Mpx a frame or photo can be")
    return size


def read_mask(path: str) -> np.ndarray:
    try:
        m = read_image(Path(path))
    except ValueError as e:
        raise UserError(f"--roi-mask {path}: {e}") from None
    m = m.max(axis=2)
    if not np.any(m):
        raise UserError(f"--roi-mask {path}: the mask is empty (no non-zero pixel)")
    return m


def annotate(img: np.ndarray, r: Result, roi: Roi | None, mask: np.ndarray | None) -> np.ndarray:
    """A copy of the image with the ROI (yellow), the centre (green; orange for a best guess)
    and the answer written in its corner; line widths grow with the image."""
    out = img.copy()
    h, w = out.shape[:2]
    t = max(1, round(min(h, w) / 300))
    if roi is not None:
        rim = roi.rim(144)
        if np.isfinite(rim).all() and np.abs(rim).max() < MAX_COORD:
            cv2.polylines(out, [np.round(rim).astype(np.int32)], True, (0, 220, 255), t, cv2.LINE_AA)
    if mask is not None:
        contours, _ = cv2.findContours((mask > 0).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(out, contours, -1, (0, 220, 255), t, cv2.LINE_AA)
    if r.pixel is not None:
        p = (round(r.pixel[0]), round(r.pixel[1]))
        colour = (0, 255, 0) if r.reason is None else (0, 140, 255)
        for c, k in (((0, 0, 0), 2 * t + 1), (colour, t)):
            cv2.drawMarker(out, p, c, cv2.MARKER_TILTED_CROSS, 14 * t + 6, k, cv2.LINE_AA)
    text = f"centre {r.confidence:.2f}" if r.reason is None else f"no answer: {r.reason}"
    s = 0.5 * t
    for c, k in (((0, 0, 0), 3 * t), ((255, 255, 255), t)):
        cv2.putText(out, text, (6 * t, 20 * t), cv2.FONT_HERSHEY_SIMPLEX, s, c, k, cv2.LINE_AA)
    return out


def _annotated_path(out_dir: Path, src: Path, taken: set[str]) -> Path:
    """`<stem>.centre.jpg` in out_dir; `<stem>-2.centre.jpg`, … when two inputs share a stem."""
    stem, k = src.stem, 1
    name = f"{stem}.centre.jpg"
    while name in taken:
        k += 1
        name = f"{stem}-{k}.centre.jpg"
    taken.add(name)
    return out_dir / name


def detect_file(shown_name: str, path: Path, roi: Roi | None, mask: np.ndarray | None) -> tuple[Result, np.ndarray | None]:
    r = Result(shown_name)
    try:
        img = read_image(path)
    except ValueError as e:
        r.error = str(e)
        return r, None
    r.height, r.width = img.shape[:2]
    if mask is not None and mask.shape[:2] != img.shape[:2]:
        r.error = f"the ROI mask is {mask.shape[1]}x{mask.shape[0]}, the image {r.width}x{r.height}"
        return r, img
    t0 = time.perf_counter()
    det: Detection = detect_centre(img, mask if mask is not None else roi)
    r.latency_ms = (time.perf_counter() - t0) * 1000
    r.pixel = None if det.pixel is None else (float(det.pixel[0]), float(det.pixel[1]))
    r.confidence, r.reason = float(det.confidence), det.reason
    return r, img


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="capm-field detect", description="The weed-centre detector on image files: the centre of the main plant in each.")
    ap.add_argument("images", nargs="+", type=cli_args.path, metavar="IMAGE|DIR", help="image files, or directories of them")
    ap.add_argument("--roi", metavar="U,V,R|U,V,W,H,ANGLE",
                    help="search only this circle (centre, radius) or ellipse (centre, full width, height, angle°), in px "
                         "(write --roi=-5,… when the first number is negative)")
    ap.add_argument("--roi-mask", metavar="FILE", help="search only where this image (the photos' size) is non-zero")
    ap.add_argument("--json", metavar="FILE", help="write every image's answer to FILE")
    ap.add_argument("--annotate", type=cli_args.path, metavar="DIR", help="write each image with its centre marked to DIR/<name>.centre.jpg")
    try:
        a = ap.parse_args(argv)
    except SystemExit as e:  # argparse printed its usage and error line already
        return 0 if e.code == 0 else 2
    if a.roi is not None and a.roi_mask is not None:
        raise UserError("give --roi or --roi-mask, not both")
    files = image_files(a.images)
    inputs = [path for _, path, _ in files if path is not None] + ([Path(a.roi_mask)] if a.roi_mask else [])
    check_output(a.json, "--json", inputs=inputs)
    roi = parse_roi(a.roi) if a.roi is not None else None
    mask = read_mask(a.roi_mask) if a.roi_mask is not None else None
    out_dir = None
    if a.annotate is not None:
        out_dir = Path(a.annotate)
        if out_dir.exists() and not out_dir.is_dir():
            raise UserError(f"--annotate {a.annotate}: is a file, not a directory")
        out_dir.mkdir(parents=True, exist_ok=True)
        if not os.access(out_dir, os.W_OK | os.X_OK):
            raise UserError(f"--annotate {a.annotate}: directory is not writable")
    cv2.setNumThreads(1)  # (the detector's figures are one core's; see docs/perception.md)
    results: list[Result] = []
    # an annotated copy never takes an input's name (`x.centre.jpg` among the photos of DIR --annotate DIR)
    taken: set[str] = {p.name for p in inputs if out_dir is not None and same_file(p.parent, out_dir)}
    interrupted = False
    try:
        for name, path, err in files:
            if path is None:
                r, img = Result(name, error=err), None
            else:
                r, img = detect_file(name, path, roi, mask)
            if out_dir is not None and img is not None and r.error is None:
                dst = _annotated_path(out_dir, path, taken)
                ok, buf = cv2.imencode(".jpg", annotate(img, r, roi, mask), [cv2.IMWRITE_JPEG_QUALITY, 90])
                try:
                    if not ok:
                        raise OSError("JPEG encoding failed")
                    buf.tofile(str(dst))
                    r.annotated = str(dst)
                except OSError as e:
                    r.error = f"cannot write {dst}: {getattr(e, 'strerror', None) or e}"
            results.append(r)
            print(r.line(), flush=True)
    except KeyboardInterrupt:
        interrupted = True
        raise
    finally:
        if a.json:
            doc = {"roi": a.roi, "roi_mask": a.roi_mask, "interrupted": interrupted, "images": [r.record() for r in results]}
            write_output(a.json, json.dumps(doc, indent=2), "--json")
    bad = sum(r.error is not None for r in results)
    answered = sum(r.error is None and r.reason is None for r in results)
    print(f"{len(results)} image(s): {answered} centre(s) found, {len(results) - answered - bad} without an answer, {bad} with an error")
    return 2 if bad else 0
