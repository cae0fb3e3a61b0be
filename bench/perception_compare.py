"""Two runs of `bench/perception_failures.py --seeds ...` compared case by case (a detector change, paired).

    .venv/bin/python bench/perception_compare.py BASE_DIR NEW_DIR [--moved-mm 1.0]

Both directories hold seed_<S>/cases.json; seeds and cases present in both are paired. Prints every
case whose verdict changed (a weed answered right ↔ wrong or missed, a bare frame's reason), then the
totals of each run (detected, wrong > 30 mm, bare soil "no_plant"), how many answers moved by more
than --moved-mm (better / worse; a miss counts as infinitely far) and the paired latency median.
Latency is comparable only for runs made one after the other on the same machine (docs/perception.md).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

WRONG_MM = 30.0  # as sim_bench.perception_bench.WRONG_MM (not imported: this reads files only)


@dataclass
class Comparison:
    """Paired totals of two runs; `changed` lists (seed, case, kind, base row, new row) whose verdict changed."""

    pairs: int = 0
    detected: list[int] = field(default_factory=lambda: [0, 0])
    wrong: list[int] = field(default_factory=lambda: [0, 0])
    bare_ok: list[int] = field(default_factory=lambda: [0, 0])
    bare: int = 0
    better: int = 0
    worse: int = 0
    latency: list[list[float]] = field(default_factory=lambda: [[], []])
    changed: list[tuple] = field(default_factory=list)


def _err(row: dict) -> float:
    e = row.get("err_mm")
    return math.inf if e is None else float(e)


def _verdict(row: dict) -> str:
    if row["kind"] == "bare":
        return str(row["reason"])
    e = _err(row)
    return "missed" if math.isinf(e) else "wrong" if e > WRONG_MM else "right"


def compare(base: dict[int, list[dict]], new: dict[int, list[dict]], moved_mm: float = 1.0) -> Comparison:
    """Pair the rows of two runs ({seed: cases.json rows}) by seed and case index."""
    out = Comparison()
    for seed in sorted(set(base) & set(new)):
        rows_new = {r["i"]: r for r in new[seed]}
        for a in base[seed]:
            b = rows_new.get(a["i"])
            if b is None:
                continue
            out.pairs += 1
            for k, r in enumerate((a, b)):
                out.latency[k].append(float(r["lat_ms"]))
            if _verdict(a) != _verdict(b):
                out.changed.append((seed, a["i"], a["kind"], a, b))
            if a["kind"] == "bare":
                out.bare += 1
                for k, r in enumerate((a, b)):
                    out.bare_ok[k] += r["reason"] == "no_plant"
                continue
            ea, eb = _err(a), _err(b)
            for k, e in enumerate((ea, eb)):
                out.detected[k] += not math.isinf(e)
                out.wrong[k] += WRONG_MM < e < math.inf
            if ea == eb or (not math.isinf(ea) and not math.isinf(eb) and abs(ea - eb) <= moved_mm):
                continue
            if eb < ea:
                out.better += 1
            else:
                out.worse += 1
    return out


def load(run_dir: Path) -> dict[int, list[dict]]:
    """{seed: rows} of a perception_failures.py --seeds output directory."""
    runs = {}
    for f in sorted(run_dir.glob("seed_*/cases.json")):
        runs[int(f.parent.name.removeprefix("seed_"))] = json.loads(f.read_text())
    return runs


def _fmt(row: dict) -> str:
    e = row.get("err_mm")
    return f"{row['reason'] or 'answer'} {'' if e is None else f'{e:.1f} mm '}({row.get('method')})"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("base", type=Path)
    ap.add_argument("new", type=Path)
    ap.add_argument("--moved-mm", type=float, default=1.0, help="an answer moved by more than this is better or worse")
    a = ap.parse_args(argv)
    base, new = load(a.base), load(a.new)
    if not base or not new:
        print(f"no seed_*/cases.json under {a.base if not base else a.new}", file=sys.stderr)
        return 2
    c = compare(base, new, a.moved_mm)
    if not c.pairs:
        print("the two runs share no seed and case", file=sys.stderr)
        return 2
    for seed, i, kind, ra, rb in c.changed:
        print(f"seed {seed} case {i} {kind}: {_fmt(ra)} -> {_fmt(rb)}")
    print(f"pairs {c.pairs}: detected {c.detected[0]} -> {c.detected[1]}, wrong {c.wrong[0]} -> {c.wrong[1]}, "
          f"bare no_plant {c.bare_ok[0]} -> {c.bare_ok[1]} of {c.bare}; moved > {a.moved_mm:g} mm: "
          f"{c.better} better, {c.worse} worse; latency median {np.median(c.latency[0]):.1f} -> "
          f"{np.median(c.latency[1]):.1f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
