"""A detector constant A/B over the held-out benches, frame by frame: which answers it moves.

    .venv/bin/python bench/heldout_pairs.py capm_field.plant_choice.WAISTED_PAIR=False [--quick]

Each held-out bench (`other_renderer_plants.py` seeds 0–2, `field_photo_weeds.py` seeds 0–1,
`photo_plants.py` seeds 3–6, each with and without a ROI; `stones_on_soils.py` seed 0, bare) runs
twice in this process: as the code stands, then with the constant set as given (a module attribute
the detector reads at call time). Every `detect_centre` call is recorded; the runs make the same
frames in the same order, so call k of one run is call k of the other. Printed: per bench, the frames
whose answer moved by > 1 px or whose reason changed, then the count. The benches' own summaries
are not printed (their stdout is swallowed); judge a move with the bench's own `--save-fails`.
`--quick`: one seed of each, no ROI runs.
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import importlib
import io
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import capm_field.detector as detector  # noqa: E402

RUNS = [  # (bench module, its arguments)
    *[("other_renderer_plants", ["--n", "100", "--seed", str(s), *roi]) for s in (0, 1, 2) for roi in ([], ["--roi"])],
    *[("field_photo_weeds", ["--n", "160", "--seed", str(s), *roi]) for s in (0, 1) for roi in ([], ["--roi"])],
    *[("photo_plants", ["--n", "70", "--seed", str(s), *roi]) for s in (3, 4, 5, 6) for roi in ([], ["--roi"])],
    ("stones_on_soils", ["--seed", "0"]),
]
QUICK = [("other_renderer_plants", ["--n", "100", "--seed", "0"]), ("field_photo_weeds", ["--n", "160", "--seed", "0"]),
         ("photo_plants", ["--n", "70", "--seed", "3"]), ("stones_on_soils", ["--seed", "0"])]


def _recorded(bench: str, args: list[str]) -> list[tuple]:
    """(pixel or None, reason) of every `detect_centre` call of one bench run."""
    calls: list[tuple] = []
    real = detector.detect_centre

    def rec(*a, **kw):
        d = real(*a, **kw)
        calls.append((d.pixel, d.reason))
        return d

    mod = importlib.import_module(bench)
    patched = [(m, n) for m, n in ((detector, "detect_centre"), (mod, "detect_centre")) if hasattr(m, n)]
    for m, n in patched:
        setattr(m, n, rec)
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            mod.main(args)
    finally:
        for m, n in patched:
            setattr(m, n, real)
    return calls


def _moved(a: tuple, b: tuple) -> bool:
    if (a[0] is None) != (b[0] is None) or a[1] != b[1]:
        return True
    return a[0] is not None and math.dist(a[0], b[0]) > 1.0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("setting", help="module.CONSTANT=value (a Python literal), the B side")
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args(argv)
    target, _, value = a.setting.partition("=")
    mod_name, _, const = target.rpartition(".")
    mod = importlib.import_module(mod_name)
    if not hasattr(mod, const):
        ap.error(f"{mod_name} has no {const}")
    old, new = getattr(mod, const), ast.literal_eval(value)
    total = 0
    for bench, args in QUICK if a.quick else RUNS:
        base = _recorded(bench, args)
        setattr(mod, const, new)
        try:
            other = _recorded(bench, args)
        finally:
            setattr(mod, const, old)
        if len(base) != len(other):
            print(f"{bench} {' '.join(args)}: {len(base)} vs {len(other)} calls, not paired")
            continue
        moved = [k for k, (x, y) in enumerate(zip(base, other)) if _moved(x, y)]
        total += len(moved)
        print(f"{bench} {' '.join(args)}: {len(moved)} of {len(base)} frames moved", flush=True)
        for k in moved:
            print(f"   call {k}: {base[k][0]} {base[k][1]} -> {other[k][0]} {other[k][1]}")
    print(f"moved in all: {total}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
