"""Parsing of list-valued command-line options, with errors a user can act on (UserError → exit 2)."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterable

from .errors import UserError


def names(text: str, allowed: Iterable[str], flag: str) -> tuple[str, ...]:
    """'a,b,c' → ('a', 'b', 'c'), each one of `allowed`, each once (`a,a` crashed the table after
    the whole bench had run; `a,,b` dropped the empty item silently)."""
    allowed = tuple(allowed)
    out = tuple(p.strip() for p in text.split(","))
    if not any(out):
        raise UserError(f"{flag}: empty list")
    for p in out:
        if not p:
            raise UserError(f"{flag}: an empty item in {text[:80]!r}")
        if p not in allowed:
            raise UserError(f"unknown planner {p[:40]!r} in {flag}; choose from {', '.join(allowed)}")
    twice = next((p for i, p in enumerate(out) if p in out[:i]), None)
    if twice:
        raise UserError(f"{flag}: {twice!r} given twice")
    return out


MAX_LIST_VALUE = 1e6  # no length (m) or density (/m²) of a bench comes near; 1e300 overflowed a planner


def floats(text: str, flag: str) -> tuple[float, ...]:
    """'2.75,-3' → (2.75, -3.0); the caller checks the range (float() also takes 'nan' and 'inf')."""
    try:
        return tuple(float(x) for x in text.split(","))
    except ValueError as e:
        raise UserError(f"{flag}: not a list of numbers: {text[:80]!r}") from e


def positive_floats(text: str, flag: str) -> tuple[float, ...]:
    """'2.75,3.25' → (2.75, 3.25), all in (0, MAX_LIST_VALUE] (a nan passes `v <= 0` and reached
    the benches as an AssertionError or an OverflowError)."""
    out = floats(text, flag)
    if not all(0 < v <= MAX_LIST_VALUE for v in out):  # false for nan too
        raise UserError(f"{flag} must be positive finite numbers ≤ {MAX_LIST_VALUE:g}, got {text[:80]}")
    return out


MAX_SEED = 2**63 - 1


def _int_in(text: str, lo: int, hi: int, shown_hi: str) -> int:
    """An argparse integer within [lo, hi], else ArgumentTypeError ("must be in [lo, shown_hi]")."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text[:30]!r}") from None
    if not lo <= n <= hi:
        raise argparse.ArgumentTypeError(f"must be in [{lo}, {shown_hi}] (got {text[:30]})")
    return n


def seed(text: str) -> int:
    """argparse type of a random seed: an integer in [0, 2⁶³) (numpy refuses negative seeds)."""
    return _int_in(text, 0, MAX_SEED, "2**63 - 1")


def count(lo: int, hi: int) -> Callable[[str], int]:
    """argparse type of an integer option within [lo, hi]: 10**30 trials or scenes ran on past any
    patience or overflowed numpy (a traceback); a negative count was read as 0."""
    bound = f"{hi:_}".replace("_", " ")  # 1 000 000
    return lambda text: _int_in(text, lo, hi, bound)


MAX_WORKERS = 64  # processes a bench forks; far above any machine this runs on (each holds the maps)
# --workers: 100 000 forked as many copies of the planning core before the first result; 0 ran one quietly
workers = count(1, MAX_WORKERS)


def path(text: str) -> str:
    """argparse type of a file or directory argument: not empty (`''` was read as "not given", or
    as the current directory: `--annotate ''` wrote into it, `--summary ''` skipped the comparison)."""
    if not text:
        raise argparse.ArgumentTypeError("empty path")
    return text
