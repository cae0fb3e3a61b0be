"""Straight thin lines in a grey image: the line filter of `capm_field.stalks`.

Per pixel, the Hessian's eigenvalue across a line (either polarity, where the one along it is
small) less EDGE_K × the gradient magnitude; its direction tensor averaged over a stalk-length
neighbourhood, whose coherent part is the "agreeing" strength (along a straight stalk the
directions agree, in the soil's texture they do not). The per-pixel parts are compiled loops
(`capm_field.compiled`); the numpy formulation they replaced is the fallback (same values to
~3e-7 of the largest, and the same direction bins but at exact ties; tests/test_stalks_lines.py).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .compiled import kernel

SIGMA = 1.0  # px: Gaussian scale of the line filter (stalks 1–3 px wide on the stalk grid)
N_DIRS = 16  # direction bins that keep crossing stalks apart
EDGE_K = 2.0  # line strength minus this × gradient magnitude (a step edge's flanks are not lines)


def line_strength(grey: np.ndarray, length: float, compiled: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Straight thin lines in a float32 grey image: (agreeing strength, direction bin, own strength).

    Own strength, per pixel: the Hessian's |eigenvalue| across a line (either polarity) where
    the one along it is small, less EDGE_K × the gradient magnitude. Agreeing strength: the
    coherent part (λ1 − λ2) of the line-direction tensor weighted by it, averaged with a
    Gaussian of σ = length / 3; its direction, in N_DIRS bins over [0, π). `compiled` False:
    the numpy formulation (also where numba cannot compile)."""
    f = cv2.GaussianBlur(grey, (0, 0), SIGMA)
    fxx = cv2.Sobel(f, cv2.CV_32F, 2, 0, ksize=3)
    fyy = cv2.Sobel(f, cv2.CV_32F, 0, 2, ksize=3)
    fxy = cv2.Sobel(f, cv2.CV_32F, 1, 1, ksize=3)
    fx = cv2.Sobel(f, cv2.CV_32F, 1, 0, ksize=3)
    fy = cv2.Sobel(f, cv2.CV_32F, 0, 1, ksize=3)
    sig = max(length / 3.0, 1.5)
    if compiled and _pixel_lines is not None and _tensor_lines is not None:
        st, txx, txy, tyy = _pixel_lines(fxx, fyy, fxy, fx, fy, np.float32(EDGE_K))
        for t in (txx, txy, tyy):
            cv2.GaussianBlur(t, (0, 0), sig, dst=t)
        best, idx = _tensor_lines(txx, txy, tyy, N_DIRS)
        return best, idx, st
    grad = np.hypot(fx, fy) / 8
    disc = np.sqrt((fxx - fyy) ** 2 + 4 * fxy**2)
    l1 = 0.5 * (fxx + fyy - disc)  # most negative: across a light line
    l2 = 0.5 * (fxx + fyy + disc)  # most positive: across a dark line
    light = np.where((l1 < 0) & (np.abs(l2) < 0.5 * np.abs(l1)), -l1, 0.0)
    dark = np.where((l2 > 0) & (np.abs(l1) < 0.5 * np.abs(l2)), l2, 0.0)
    st = np.maximum(np.maximum(light, dark) / 4 - EDGE_K * grad, 0.0).astype(np.float32)
    # the direction along the line: perpendicular to the eigenvector of the eigenvalue used
    phi = 0.5 * np.arctan2(2 * fxy, fxx - fyy)  # eigenvector of l2 (across a dark line)
    along = np.where(light > dark, phi, phi + np.pi / 2)
    # line-direction tensor of the strengths, averaged over ~`length` px: a straight line keeps
    # one direction (its coherent part, λ1 − λ2, stays), soil texture's lines point every way
    c, s_ = np.cos(along), np.sin(along)
    txx = cv2.GaussianBlur((st * c * c).astype(np.float32), (0, 0), sig)
    txy = cv2.GaussianBlur((st * c * s_).astype(np.float32), (0, 0), sig)
    tyy = cv2.GaussianBlur((st * s_ * s_).astype(np.float32), (0, 0), sig)
    best = np.sqrt((txx - tyy) ** 2 + 4 * txy**2)
    th = 0.5 * np.arctan2(2 * txy, txx - tyy)  # the dominant line direction
    idx = (np.round(np.mod(th, np.pi) / (np.pi / N_DIRS)).astype(np.int32) % N_DIRS).astype(np.uint8)
    return best, idx, st


_F32 = lambda nb: nb.types.Array(nb.float32, 2, "C", readonly=True)  # noqa: E731


@kernel(lambda nb: nb.types.UniTuple(nb.float32[:, ::1], 4)(*[_F32(nb)] * 5, nb.float32))
def _pixel_lines(fxx, fyy, fxy, fx, fy, edge_k):  # pragma: no cover - compiled; tested against numpy
    """Own strength st and the tensor st·(cos², cos·sin, sin²) of the direction along the line, per
    pixel, in float32 as the numpy formulation. The direction's squares come from the Hessian's
    double angle (cos 2φ = (fxx − fyy) / disc, sin 2φ = 2 fxy / disc) instead of atan2, cos and
    sin: the same to float32 rounding, 3× faster (session 69)."""
    h, w = fxx.shape
    st = np.empty((h, w), np.float32)
    txx = np.empty((h, w), np.float32)
    txy = np.empty((h, w), np.float32)
    tyy = np.empty((h, w), np.float32)
    zero, half, one = np.float32(0.0), np.float32(0.5), np.float32(1.0)
    four, eight = np.float32(4.0), np.float32(8.0)
    for i in range(h):
        for j in range(w):
            a, b, c = fxx[i, j], fyy[i, j], fxy[i, j]
            gx, gy = fx[i, j], fy[i, j]
            dd = a - b
            disc = np.sqrt(dd * dd + four * (c * c))
            l1 = half * (a + b - disc)
            l2 = half * (a + b + disc)
            light = -l1 if (l1 < zero and abs(l2) < half * abs(l1)) else zero
            dark = l2 if (l2 > zero and abs(l1) < half * abs(l2)) else zero
            s = max(max(light, dark) / four - edge_k * (np.sqrt(gx * gx + gy * gy) / eight), zero)
            st[i, j] = s
            if s == zero:
                txx[i, j] = zero
                txy[i, j] = zero
                tyy[i, j] = zero
                continue
            c2, s2 = (dd / disc, (c + c) / disc) if disc > zero else (one, zero)
            if not light > dark:  # along a dark line: φ + π/2, the double angle turned by π
                c2, s2 = -c2, -s2
            txx[i, j] = s * (half * (one + c2))
            tyy[i, j] = s * (half * (one - c2))
            txy[i, j] = s * (half * s2)
    return st, txx, txy, tyy


@kernel(lambda nb: nb.types.Tuple((nb.float32[:, ::1], nb.uint8[:, ::1]))(*[_F32(nb)] * 3, nb.int64))
def _tensor_lines(txx, txy, tyy, n_dirs):  # pragma: no cover - compiled; tested against numpy
    """The averaged tensor's coherent part √((txx − tyy)² + 4 txy²) and its direction's bin of n_dirs
    over [0, π), per pixel."""
    h, w = txx.shape
    best = np.empty((h, w), np.float32)
    idx = np.empty((h, w), np.uint8)
    four = np.float32(4.0)
    step = math.pi / n_dirs
    for i in range(h):
        for j in range(w):
            a, b, c = txx[i, j], tyy[i, j], txy[i, j]
            dd = a - b
            best[i, j] = np.sqrt(dd * dd + four * (c * c))
            th = 0.5 * math.atan2(2.0 * c, dd)  # (−π/2, π/2]
            if th < 0.0:
                th += math.pi
            idx[i, j] = int(math.floor(th / step + 0.5)) % n_dirs
    return best, idx
