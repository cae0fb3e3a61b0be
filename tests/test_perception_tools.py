"""The perception bench's helper scripts: paired comparison, back-to-back latency, the per-case trace."""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _module(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "bench" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod  # (its dataclasses look their module up there)
    spec.loader.exec_module(mod)
    return mod


def _row(i, kind, err=None, reason=None, lat=10.0):
    return {"i": i, "kind": kind, "err_mm": err, "reason": reason, "lat_ms": lat, "method": "m"}


def test_compare_pairs_cases_and_counts_moves_both_ways():
    cmp = _module("perception_compare")
    base = {0: [_row(0, "seedling", 2.0), _row(1, "clover", 40.0), _row(2, "grass", None, "no_plant"),
                _row(3, "bare", reason="no_plant"), _row(4, "rosette", 5.0)],
            7: [_row(0, "grass", 3.0)]}  # seed 7 only in the base: not paired
    new = {0: [_row(0, "seedling", 2.5), _row(1, "clover", 3.0), _row(2, "grass", 8.0),
               _row(3, "bare", reason=None), _row(4, "rosette", 200.0), _row(9, "grass", 1.0)]}
    c = cmp.compare(base, new, moved_mm=1.0)
    assert c.pairs == 5 and c.bare == 1
    assert c.detected == [3, 4] and c.wrong == [1, 1] and c.bare_ok == [1, 0]
    assert (c.better, c.worse) == (2, 1)  # 40 → 3 and a miss → 8 better; 5 → 200 worse; 2.0 → 2.5 within 1 mm
    assert [(s, i) for s, i, *_ in c.changed] == [(0, 1), (0, 2), (0, 3), (0, 4)]


def test_compare_cli_reads_run_directories(tmp_path):
    for name, err in (("a", 40.0), ("b", 2.0)):
        d = tmp_path / name / "seed_3"
        d.mkdir(parents=True)
        (d / "cases.json").write_text(json.dumps([_row(5, "clover", err)]))
    out = subprocess.run([sys.executable, str(ROOT / "bench" / "perception_compare.py"), str(tmp_path / "a"),
                          str(tmp_path / "b")], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "seed 3 case 5 clover: answer 40.0 mm (m) -> answer 2.0 mm (m)" in out.stdout
    assert "wrong 1 -> 0" in out.stdout and "1 better, 0 worse" in out.stdout
    empty = subprocess.run([sys.executable, str(ROOT / "bench" / "perception_compare.py"), str(tmp_path / "a"),
                            str(tmp_path / "none")], capture_output=True, text=True, timeout=60)
    assert empty.returncode == 2 and "no seed_*/cases.json" in empty.stderr


def test_latency_and_trace_run_on_rendered_cases(tmp_path):
    """Both scripts render what the cache lacks and report every case they were given."""
    lat = subprocess.run([sys.executable, str(ROOT / "bench" / "perception_latency.py"), "--scenes", "3",
                          "--cache", str(tmp_path / "c")], capture_output=True, text=True, timeout=300)
    assert lat.returncode == 0, lat.stderr
    n = int(lat.stdout.split(": ")[1].split(" frames")[0])
    assert n >= 1 and "latency median" in lat.stdout and len(list((tmp_path / "c").glob("*.png"))) == n
    tr = subprocess.run([sys.executable, str(ROOT / "bench" / "perception_trace.py"), "--scenes", "3",
                         "--cache", str(tmp_path / "c"), "0", "1", "2"], capture_output=True, text=True, timeout=300)
    assert tr.returncode == 0, tr.stderr
    heads = [ln for ln in tr.stdout.splitlines() if ln.startswith("== seed 0 case ")]
    assert [h.split()[4].rstrip(":") for h in heads] == ["0", "1", "2"]


def test_heldout_pairs_makes_bench_frames_and_scores_them(capsys):
    import numpy as np
    import pytest

    hp = _module("heldout_pairs")
    (i, kind, img, rois, truth, S), = list(hp.frames("photo_plants", 3, 1))
    assert (i, kind) == (0, "dandelion") and len(rois) == 2 and rois[0] is None and truth is not None and S > 0
    assert hp.error(img, rois[1], truth, S) < 0.2  # the bench's own first dandelion, found
    blank = np.full((240, 320, 3), 90, np.uint8)
    assert hp.error(blank, None, None, 1.0) == 0.0  # bare soil: no plant is right
    assert hp.error(blank, None, (10.0, 10.0), 50.0) == float("inf")  # a weed frame without an answer
    stones = hp.frames("stones_on_soils", 0, 0)
    assert next(stones)[4] is None
    for bad in ("capm_field.centre_cascade.NO_SUCH=1", "capm_field.centre_cascade.MIDRIBS=notaliteral",
                "no_such_module.X=1"):
        with pytest.raises(SystemExit):
            hp.main([bad])
    capsys.readouterr()
