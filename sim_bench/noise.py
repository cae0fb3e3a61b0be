"""Hashed value noise evaluated in field coordinates.

The lattice values come from an integer hash of (seed, channel, i, j), so a texture is a
continuous function of the ground point: tiles rendered separately (or at different levels of
detail) join without seams, and a scene is reproducible from its seed alone.
"""

from __future__ import annotations

import numpy as np

_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)


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
