"""`capm-field review`: run logs (complete and crash-truncated) → real Rerun recordings (.rrd)."""

from __future__ import annotations

import io
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from rerun.chunk import RrdReader

from capm_field import cli
from capm_field.camera import PinholeCamera
from capm_field.config import CameraConfig
from capm_field.errors import UserError
from capm_field.keystates import TROI
from mission.review import main as review_main
from mission.runlog import RunLog
from mission.runlog_synth import synthetic_mission
from rerun_recording import rrd_contents

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def run_mcap(tmp_path_factory, robot) -> Path:
    path = tmp_path_factory.mktemp("review") / "run.mcap"
    cam = PinholeCamera.from_config(CameraConfig())
    with RunLog(path, robot, cam, bench=True) as log:
        synthetic_mission(log, n_targets=3, seconds_per_target=2.0, images_per_target=1, width=640, height=360)
    return path


def test_review_rrd_has_image_transforms_series_and_overlays(run_mcap, tmp_path):
    out = tmp_path / "out.rrd"
    # The real console entry point, in a subprocess (no viewer is started with --rrd).
    proc = subprocess.run(
        [sys.executable, "-m", "capm_field.cli", "review", str(run_mcap), "--rrd", str(out)],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert "wrote" in proc.stdout
    reader = RrdReader(out)
    assert reader.recordings() and reader.blueprints()  # the layout travels with the data
    ents = rrd_contents(out)
    assert "EncodedImage:blob" in ents["/camera/image"]
    assert "Pinhole:image_from_camera" in ents["/camera/calibration"]
    assert {"Transform3D:child_frame", "Transform3D:parent_frame"} <= ents["/tf"]
    assert "TextLog:text" in ents["/log"]
    assert any(e.startswith("/z1_description") for e in ents)  # URDF from /robot_description
    for series in ("/plots/igniter/flame_on", "/plots/energy/total"):
        assert "Scalars:scalars" in ents[series]
    assert "SeriesLines:names" in ents["/plots/igniter/flame_on"]
    assert {"LineStrips3D:strips", "LineStrips3D:labels"} <= ents["/review/troi"]  # every TROI, one entity
    assert "Points3D:positions" in ents["/review/troi/centres"] and "Points3D:labels" in ents["/review/truth"]
    assert "LineStrips3D:strips" in ents["/review/regions/t00/R_o"]
    assert "Points3D:labels" in ents["/review/key_states/t00"]
    assert "Points3D:positions" in ents["/review/detection/t00"]
    assert "Points2D:positions" in ents["/camera/image/detection"]
    assert "LineStrips2D:strips" in ents["/camera/image/roi"]  # the ROI searched, on the raw image
    assert "message_log_time" in ents["/review/key_states/t00"]  # same timeline as the native import


def test_review_opens_a_truncated_crash_file(run_mcap, tmp_path):
    data = run_mcap.read_bytes()
    cut = tmp_path / "crash.mcap"
    cut.write_bytes(data[: int(len(data) * 0.6)])  # no summary, no footer, a torn chunk
    out = tmp_path / "crash.rrd"
    assert cli.main(["review", str(cut), "--rrd", str(out)]) == 0
    ents = rrd_contents(out)
    assert "Transform3D:child_frame" in ents["/tf"]
    assert "Scalars:scalars" in ents["/plots/igniter/flame_on"]


@pytest.mark.parametrize(
    "content",
    [None, b"", b"hello, not an mcap file\n", b"\x89MCAP0\r\n" + b"\xff" * 64],
    ids=["missing", "empty", "text", "mcap-magic-then-garbage"],
)
def test_bad_files_exit_2_with_one_line(tmp_path, capsys, content):
    path = tmp_path / "bad.mcap"
    if content is not None:
        path.write_bytes(content)
    assert cli.main(["review", str(path), "--rrd", str(tmp_path / "x.rrd")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("capm-field review: error:") and "\n" not in err and "Traceback" not in err


def test_rerun_binary_is_found():
    from mission.review import _rerun_binary

    assert shutil.which(_rerun_binary()) or Path(_rerun_binary()).is_file()


def test_a_run_directory_stands_for_its_log(tmp_path, capsys):
    """`capm-field review runs/x` opens runs/x/run.mcap; a directory without one is one line."""
    from mission.runlog_read import check_mcap

    (tmp_path / "run.mcap").write_bytes(b"\x89MCAP0\r\n")
    assert check_mcap(tmp_path) == tmp_path / "run.mcap"
    empty = tmp_path / "empty"
    empty.mkdir()
    assert cli.main(["review", str(empty), "--rrd", str(tmp_path / "x.rrd")]) == 2
    assert "is a directory without a run.mcap" in capsys.readouterr().err


def test_target_ids_with_slashes_and_spaces_are_one_entity_each(tmp_path, robot):
    """TROI ids are free text (a prescan tool's "plot A/3"): review escapes them, so each target's
    regions stay one entity under /review/regions instead of splitting into a path."""
    path = tmp_path / "run.mcap"
    with RunLog(path, robot, PinholeCamera.from_config(CameraConfig()), bench=True) as log:
        for k, tid in enumerate(("plot A/3", "W.1")):
            log.regions(10**9 + k, tid, TROI(1.0 + k, 0.0, 0.2, tid), [(0.3, 0.6)], [], None)
    out = tmp_path / "out.rrd"
    assert review_main([str(path), "--rrd", str(out)]) == 0
    ents = rrd_contents(out)
    ro = sorted(e for e in ents if e.startswith("/review/regions/") and e.endswith("/R_o"))
    assert ro == ["/review/regions/W.1/R_o", "/review/regions/plot\\ A\\/3/R_o"], ro  # escaped: one part each


def test_review_entities_do_not_grow_by_one_per_target_and_kind(tmp_path, robot):
    """A 2 000-target run's review failed (Rerun: "TooManyTables", nothing written): ~11 entities
    per target, each with a static coordinate-frame chunk of its own, were more chunks than Rerun's
    file index holds. TROIs and the bench truth are one entity each, and an entity's frame rides in
    its first row."""
    path = tmp_path / "run.mcap"
    n = 300
    with RunLog(path, robot, PinholeCamera.from_config(CameraConfig()), bench=True) as log:
        for k in range(n):
            tid = f"T{k:03d}"
            log.truth_mpoi(10**9, tid, (0.5 * k, 0.1))
            log.regions(2 * 10**9 + k, tid, TROI(0.5 * k, 0.0, 0.2, tid), [(0.3, 0.6)], [(0.2, 0.5)], None)
    out = tmp_path / "out.rrd"
    assert review_main([str(path), "--rrd", str(out)]) == 0
    ents = rrd_contents(out)
    review = [e for e in ents if e.startswith("/review/")]
    assert len(review) <= 2 * n + 5, len(review)  # R_o and R_m per target; TROIs, centres, truth once
    chunks = sum(1 for c in RrdReader(out).stream() if c.entity_path.startswith("/review/"))
    assert chunks <= 2 * n + 5, chunks  # one chunk per entity: no separate static frame chunks


@pytest.mark.parametrize("make", ["fifo", "missing"])
def test_a_run_log_that_is_not_a_regular_file_is_said_so(tmp_path, make):
    """A FIFO (or a device) as the run log was "run log not found": it exists, and reading it would block."""
    from mission.runlog_read import check_mcap

    p = tmp_path / "run.mcap"
    if make == "fifo":
        os.mkfifo(p)
    with pytest.raises(UserError, match="not a regular file" if make == "fifo" else "run log not found"):
        check_mcap(p)


def test_an_entitys_frame_is_in_its_earliest_row_even_from_an_out_of_order_log(tmp_path, robot):
    """The frame rides in an entity's first row (not a static chunk of its own): a log whose
    messages are out of time order must still give the frame at the entity's earliest time, or
    its earlier rows would be drawn in no frame."""
    path = tmp_path / "run.mcap"
    with RunLog(path, robot, PinholeCamera.from_config(CameraConfig()), bench=True) as log:
        log.regions(3 * 10**9, "A", TROI(1.0, 0.0, 0.2, "A"), [(0.3, 0.6)], [], None)
        log.regions(2 * 10**9, "A", TROI(1.0, 0.0, 0.2, "A"), [(0.3, 0.7)], [], None)  # written later, earlier time
    out = tmp_path / "out.rrd"
    assert review_main([str(path), "--rrd", str(out)]) == 0
    times, framed = [], []
    for c in RrdReader(out).stream():
        if c.entity_path == "/review/regions/A/R_o":
            rb = c.to_record_batch()
            t = rb.column("message_log_time").cast("int64").to_pylist()
            times += t
            if "CoordinateFrame:frame" in rb.schema.names:
                framed += [ti for ti, f in zip(t, rb.column("CoordinateFrame:frame").to_pylist()) if f is not None]
    assert sorted(times) == [2 * 10**9, 3 * 10**9] and framed == [min(times)], (times, framed)


def test_a_cleared_image_overlay_gets_its_frame_again(tmp_path, robot):
    """A miss clears `/camera/image/detection`; a Clear hides every earlier component of the
    entity, its frame (now in its first row, no longer static) too, so the next detection must give
    the frame again or it is drawn in no frame (a review)."""
    path = tmp_path / "run.mcap"
    with RunLog(path, robot, PinholeCamera.from_config(CameraConfig()), bench=True) as log:
        for k, pixel in enumerate(((600.0, 300.0), None, (610.0, 320.0))):
            log.detection(10**9 * (k + 1), "A", pixel, 0.9 if pixel else 0.0, None if pixel else "no_plant",
                          (1.0, 0.0) if pixel else None)
    out = tmp_path / "out.rrd"
    assert review_main([str(path), "--rrd", str(out)]) == 0
    framed = []
    for c in RrdReader(out).stream():
        if c.entity_path == "/camera/image/detection" and "CoordinateFrame:frame" in c.to_record_batch().schema.names:
            rb = c.to_record_batch()
            framed += [t for t, f in zip(rb.column("message_log_time").cast("int64").to_pylist(),
                                         rb.column("CoordinateFrame:frame").to_pylist()) if f is not None]
    assert sorted(framed) == [10**9, 3 * 10**9], framed


def _images_in(path: Path) -> int:
    return sum(c.num_rows for c in RrdReader(path).stream()
               if c.entity_path == "/camera/image" and "EncodedImage:blob" in c.to_record_batch().schema.names)


def test_a_part_of_a_long_run_is_reviewed_with_the_robot_and_only_its_targets(tmp_path, robot, capsys, monkeypatch):
    """Rerun cannot hold a run of thousands of targets (its file index fails past ~50 000 chunks,
    nothing written): `--targets A-B` reviews a part, the robot's description (written once at the
    start) included, and a run longer than PART_TARGETS is reviewed its first part by default."""
    import mission.review as review

    path = tmp_path / "run.mcap"
    with RunLog(path, robot, PinholeCamera.from_config(CameraConfig()), bench=True) as log:
        synthetic_mission(log, n_targets=6, seconds_per_target=1.0, images_per_target=1, width=320, height=180)
    whole, part = tmp_path / "whole.rrd", tmp_path / "part.rrd"
    assert review_main([str(path), "--rrd", str(whole)]) == 0
    assert review_main([str(path), "--rrd", str(part), "--targets", "2-3"]) == 0
    assert "targets 2–3 of 6 (t02 … t03)" in capsys.readouterr().out
    ents = rrd_contents(part)
    assert sorted(e.split("/")[3] for e in ents if e.startswith("/review/regions/")) == ["t02", "t02", "t03", "t03"]
    assert sorted(e for e in ents if e.startswith("/review/key_states/") and e.count("/") == 3) == [
        "/review/key_states/t02", "/review/key_states/t03"]
    assert any(e.startswith("/z1_description") for e in ents)  # the URDF, logged before the part began
    assert "Points3D:labels" in ents["/review/truth"]  # truth given at its target's time, kept by target
    assert _images_in(whole) == 6 and _images_in(part) == 2

    capsys.readouterr()
    monkeypatch.setattr(review, "PART_TARGETS", 4)  # a run longer than a part: its first part, said so
    assert review_main([str(path), "--rrd", str(part)]) == 0
    err = capsys.readouterr().err
    assert "holds 6 targets" in err and "reviewing targets 0–3" in err and "--targets 4-5" in err, err
    assert _images_in(part) == 4


@pytest.mark.parametrize("spec, why", [("3-1", "after the last"), ("x", "give A-B"), ("9", "holds 6 targets")])
def test_a_bad_part_is_one_line(tmp_path, robot, capsys, spec, why):
    path = tmp_path / "run.mcap"
    with RunLog(path, robot, PinholeCamera.from_config(CameraConfig()), bench=True) as log:
        synthetic_mission(log, n_targets=6, seconds_per_target=0.5, images_per_target=1, width=320, height=180)
    assert cli.main(["review", str(path), "--rrd", str(tmp_path / "x.rrd"), "--targets", spec]) == 2
    err = capsys.readouterr().err
    assert why in err and err.count("\n") == 1, err
    assert not (tmp_path / "x.rrd").exists()


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.mark.parametrize("quiet", [False, True])
def test_a_review_shows_its_progress_on_a_terminal(run_mcap, tmp_path, monkeypatch, quiet):
    """A 1 000-target log takes ~20 s to review (a 1 500-target part ~60 s): each phase shows a
    progress bar on a terminal's stderr, none with --quiet (nor when stderr is not a terminal)."""
    err = _Terminal()
    monkeypatch.setattr(sys, "stderr", err)
    assert review_main([str(run_mcap), "--rrd", str(tmp_path / "out.rrd")] + (["--quiet"] if quiet else [])) == 0
    shown = err.getvalue()
    for phase in ("reading the run log", "Rerun's import", "drawing plans"):
        assert (phase in shown) != quiet, shown
