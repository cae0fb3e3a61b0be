"""Hashed value noise evaluated in field coordinates.

The lattice values come from an integer hash of (seed, channel, i, j), so a texture is a
continuous function of the ground point: tiles rendered separately (or at different levels of
detail) join without seams, and a scene is reproducible from its seed alone.

Two evaluators:
  * `value_noise` / `fractal`: any grid of coordinates, one dense Catmull-Rom interpolation per
    octave (exact reference; slow for fine octaves).
  * `fractal_grid`: the fast path used by the renderer. Octave spacings are powers of two of
    `LATTICE_UNIT` (so they align with the texel grids of every level of detail); octaves are
    summed on their lattices from coarse to fine, each coarser sum being upsampled ×2 with a
    cubic `cv2.resize`, and only the finest lattice is upsampled to texels. Cost ≈ one resize of
    the output plus hashing a third of the output's pixel count, for any number of octaves and up
    to several fields at once. Lattice point j of spacing s sits at (j + ½)·s, texel t of size r
    at (t + ½)·r: with cv2.resize's pixel-centre convention an integer ×f upsampling of a lattice
    window starting at index j0 lands exactly on texels j0·f + i, so windows computed for
    different tiles agree where they overlap (seamless).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)

LATTICE_UNIT = 0.0005  # m: fast-path octave spacings are LATTICE_UNIT·2^q (q ≥ 1)


def hash_u01(seed: int, channel: int, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Uniform [0, 1) values from integer lattice coordinates (splitmix64 finaliser)."""
    with np.errstate(over="ignore"):
        z = (
            np.asarray(i, dtype=np.int64).astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)
            ^ np.asarray(j, dtype=np.int64).astype(np.uint64) * np.uint64(0xC2B2AE3D27D4EB4F)
            ^ np.uint64((seed * 1_000_003 + channel * 7919) & 0xFFFFFFFFFFFFFFFF)
        )
        z = (z ^ (z >> np.uint64(30))) * _M1
        z = (z ^ (z >> np.uint64(27))) * _M2
        z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)).astype(np.float64) / float(1 << 53)


def _weights(coords: np.ndarray, spacing: float) -> tuple[np.ndarray, int]:
    """Cubic (Catmull-Rom) interpolation matrix from lattice values to `coords` (1-D)."""
    g = coords / spacing
    i0 = np.floor(g).astype(np.int64)
    f = g - i0
    lo = int(i0.min()) - 1
    n = int(i0.max()) + 3 - lo
    W = np.zeros((len(coords), n))
    f2, f3 = f * f, f * f * f
    w = (
        0.5 * (-f3 + 2 * f2 - f),
        0.5 * (3 * f3 - 5 * f2 + 2),
        0.5 * (-3 * f3 + 4 * f2 + f),
        0.5 * (f3 - f2),
    )
    rows = np.arange(len(coords))
    for k in range(4):
        W[rows, i0 - lo - 1 + k] += w[k]
    return W, lo


def value_noise(seed: int, channel: int, spacing: float, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """One octave of value noise in [-1, 1] (approx.) on the grid ys × xs (metres)."""
    Wx, lx = _weights(np.asarray(xs, float), spacing)
    Wy, ly = _weights(np.asarray(ys, float), spacing)
    I, J = np.meshgrid(np.arange(Wx.shape[1]) + lx, np.arange(Wy.shape[1]) + ly)
    L = hash_u01(seed, channel, I, J) * 2.0 - 1.0
    return Wy @ L @ Wx.T


def fractal(
    seed: int, channel: int, xs: np.ndarray, ys: np.ndarray, coarsest: float, finest: float, gain: float = 0.55
) -> np.ndarray:
    """Sum of octaves from `coarsest` down to `finest` spacing (m), normalised to unit std roughly."""
    out = np.zeros((len(ys), len(xs)))
    s, a, total = coarsest, 1.0, 0.0
    k = 0
    while s >= finest * 0.999:
        out += a * value_noise(seed, channel * 64 + k, s, xs, ys)
        total += a * a
        s *= 0.5
        a *= gain
        k += 1
    return out / max(np.sqrt(total), 1e-9) * 2.0


# ---- fast path: hierarchical octave sum on power-of-two lattices -----------------------------------
def _q(spacing: float) -> int:
    return int(round(math.log2(max(spacing, 1e-12) / LATTICE_UNIT)))


def _support(lo: int, hi: int, f: int) -> tuple[int, int]:
    """Coarse lattice window whose cubic ×f upsampling covers fine indices lo..hi (inclusive)."""
    return math.floor((lo + 0.5) / f - 0.5) - 1, math.floor((hi + 0.5) / f - 0.5) + 2


def _up(a: np.ndarray, lo: tuple[int, int], f: int, want: tuple[int, int, int, int]) -> np.ndarray:
    """Cubic ×f upsampling of window `a` (origin lo = (ylo, xlo)) cropped to want = (y0, y1, x0, x1)."""
    up = cv2.resize(a, (a.shape[1] * f, a.shape[0] * f), interpolation=cv2.INTER_CUBIC)
    if up.ndim == 2:
        up = up[..., None]
    y0, y1, x0, x1 = want
    return up[y0 - lo[0] * f : y1 - lo[0] * f + 1, x0 - lo[1] * f : x1 - lo[1] * f + 1]


def fractal_grid(
    seed: int, fields: list[tuple[int, float, float, float]], gx0: int, gy0: int, w: int, h: int, level_q: int
) -> np.ndarray:
    """Several fractal noise fields on a texel grid, (h, w, len(fields)) float32, roughly unit std ×2.

    fields: (channel, coarsest, finest, gain) per output field, spacings in metres (snapped to
    LATTICE_UNIT·2^q and never finer than two texels). Texels are LATTICE_UNIT·2^level_q wide;
    texel (row i, col j) of the output is global texel (gy0 + i, gx0 + j), centre at
    ((gx0 + j + ½)·r, (gy0 + i + ½)·r).
    """
    nf = len(fields)
    spans = []
    for ch, c, fi, g in fields:
        qc = _q(c)
        qf = max(_q(fi), level_q + 1)
        qc = max(qc, qf)
        amps = {q: g ** (qc - q) for q in range(qf, qc + 1)}
        norm = 2.0 / max(math.sqrt(sum(a * a for a in amps.values())), 1e-9)
        spans.append((ch, qf, qc, {q: a * norm for q, a in amps.items()}))
    q_fine = min(s[1] for s in spans)
    q_coarse = max(s[2] for s in spans)
    f_last = 2 ** (q_fine - level_q)
    # windows from fine to coarse (inclusive lattice index ranges)
    wy = [_support(gy0, gy0 + h - 1, f_last)]
    wx = [_support(gx0, gx0 + w - 1, f_last)]
    for _ in range(q_fine + 1, q_coarse + 1):
        wy.append(_support(*wy[-1], 2))
        wx.append(_support(*wx[-1], 2))
    acc = None
    for q in range(q_coarse, q_fine - 1, -1):
        k = q - q_fine
        (ylo, yhi), (xlo, xhi) = wy[k], wx[k]
        if acc is not None:
            (pylo, _), (pxlo, _) = wy[k + 1], wx[k + 1]
            acc = np.ascontiguousarray(_up(acc, (pylo, pxlo), 2, (ylo, yhi, xlo, xhi)))
        else:
            acc = np.zeros((yhi - ylo + 1, xhi - xlo + 1, nf), np.float32)
        J, I = np.meshgrid(np.arange(ylo, yhi + 1), np.arange(xlo, xhi + 1), indexing="ij")
        for n, (ch, qf, qc, amps) in enumerate(spans):
            if qf <= q <= qc:
                acc[..., n] += (amps[q] * (hash_u01(seed, ch * 64 + q, I, J) * 2.0 - 1.0)).astype(np.float32)
    (ylo, _), (xlo, _) = wy[0], wx[0]
    return _up(acc, (ylo, xlo), f_last, (gy0, gy0 + h - 1, gx0, gx0 + w - 1))
