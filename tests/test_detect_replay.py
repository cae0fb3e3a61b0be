"""`capm-field detect-replay`: a run log's images through the detector again (mission/detect_replay.py),
and `output.image_format: png`, which makes that replay exact.

Real bench missions (`capm-field run`, in a subprocess as a user runs it), real MCAP files; the replay
in-process so that an uncaught exception fails the test itself.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from capm_field import cli
from mission import detect_replay
from mission.executive import ROI_MARGIN

CLI = [sys.executable, "-m", "capm_field.cli"]

MISSION = """\
field:
  trois:
    - {{id: A, x: 1.0, y: 0.3, r: 0.22}}
    - {{id: B, x: 2.0, y: 0.8, r: 0.25}}
    - {{id: C, x: 1.2, y: 1.6, r: 0.24}}
start: {{x: 0.0, y: 0.0, yaw: 0.0}}
{robot}drivers: {{kind: bench, seed: 3}}
output: {{dir: {out}, {output}}}
"""
LENS = "robot: {camera: {distortion: [-0.25, 0.08, 0.0005, -0.0008, -0.01]}}\n"


def _start(d: Path, output: str, robot: str = "") -> tuple[subprocess.Popen, Path]:
    m = d / "m.yaml"
    m.write_text(MISSION.format(out=d / "out", output=output, robot=robot))
    return subprocess.Popen(CLI + ["run", str(m), "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True), d / "out"


def _run(d: Path, output: str, robot: str = "") -> Path:
    proc, out = _start(d, output, robot)
    _, err = proc.communicate(timeout=240)
    assert proc.returncode == 0, err
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    """The same bench mission logged as PNG, as JPEG, and as PNG through a distorting lens (the three
    runs side by side: each is mostly one core's work)."""
    started = {
        "png": _start(tmp_path_factory.mktemp("png"), "image_format: png"),
        "jpeg": _start(tmp_path_factory.mktemp("jpeg"), "image_format: jpeg"),
        "lens": _start(tmp_path_factory.mktemp("lens"), "image_format: png", LENS),
    }
    try:
        for proc, _ in started.values():
            _, err = proc.communicate(timeout=240)
            assert proc.returncode == 0, err
    finally:
        for proc, _ in started.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    return {k: out for k, (_, out) in started.items()}


def _replay(capsys, run: Path, tmp_path: Path, *extra: str) -> tuple[int, dict | None, str, str]:
    out_json = tmp_path / "r.json"
    rc = cli.main(["detect-replay", str(run), "--json", str(out_json), *extra])
    out, err = capsys.readouterr()
    return rc, (json.loads(out_json.read_text()) if out_json.exists() else None), out, err


@pytest.mark.parametrize("kind", ["png", "lens"])
def test_a_lossless_log_replays_every_answer_exactly(runs, capsys, tmp_path, kind):
    """Rebuilt from /tf, /camera/calibration and the TROI, the ROI is the one the executive searched
    (its rim on the logged one), and on the frame the detector saw the answers are the run's."""
    rc, doc, out, _ = _replay(capsys, runs[kind], tmp_path)
    assert rc == 0
    s, rows = doc["summary"], doc["detections"]
    assert s["detections"] >= 3 and s["replayed"] == s["detections"]
    assert s["max_rim_px"] < 1e-6
    for r in rows:
        assert r["error"] is None and r["reason"] == r["logged_reason"]
        if r["logged_pixel"] is not None:
            assert r["moved_px"] < 1e-6
    assert s["found_now"] == s["found_logged"] >= 3
    now, logged = s["error_mm_now"], s["error_mm_logged"]
    assert now["n"] == logged["n"] >= 3 and now["wrong"] == logged["wrong"]  # the bench truth is read
    assert now["median"] == pytest.approx(logged["median"], abs=1e-6)  # (the pose from /tf's quaternions)
    assert f"{s['replayed']} of {s['detections']} detections replayed" in out


def test_a_jpeg_log_replays_on_the_same_roi(runs, capsys, tmp_path):
    rc, doc, _, _ = _replay(capsys, runs["jpeg"], tmp_path, "--quiet")
    assert rc == 0
    s = doc["summary"]
    assert s["replayed"] == s["detections"] >= 3 and s["max_rim_px"] < 1e-6
    # (the answers themselves may move with the compression, by tens of px: that is what png is for)
    assert all(r["error"] is None for r in doc["detections"])


def test_png_images_are_lossless_and_read_by_rerun(runs, tmp_path):
    import cv2
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    sys.path.insert(0, str(Path(__file__).parent))
    from rerun_recording import rrd_contents

    with open(runs["png"] / "run.mcap", "rb") as f:
        msgs = [m for _, _, _, m in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(topics=["/camera/image"])]
    assert msgs and all(m.format == "png" for m in msgs)
    img = cv2.imdecode(np.frombuffer(msgs[0].data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img.shape == (720, 1280, 3)
    rrd = tmp_path / "r.rrd"
    assert cli.main(["review", str(runs["png"] / "run.mcap"), "--rrd", str(rrd)]) == 0
    assert "EncodedImage:blob" in rrd_contents(rrd)["/camera/image"]


def test_a_roi_rebuilt_another_way_is_refused_not_compared(runs, capsys, tmp_path, monkeypatch):
    """The rim check is what makes a replay's comparison mean anything: with another margin the
    rebuilt ROI misses the logged rim and nothing is compared."""
    real = detect_replay.roi_for
    monkeypatch.setattr(detect_replay, "roi_for", lambda cam, T, xy, r: real(cam, T, xy, r * 1.4 / ROI_MARGIN))
    rc, doc, _, err = _replay(capsys, runs["png"], tmp_path)
    assert rc == 2 and doc is None
    assert "none of its" in err and "px off the logged one" in err


def test_a_log_without_images_is_one_line(tmp_path, capsys):
    run = _run(tmp_path, "images: false")
    rc, doc, _, err = _replay(capsys, run, tmp_path)
    assert rc == 2 and doc is None and "stored no images" in err and len(err.strip().splitlines()) == 1


def test_image_format_is_checked_with_the_mission(tmp_path, capsys):
    m = tmp_path / "m.yaml"
    m.write_text(MISSION.format(out=tmp_path / "out", output="image_format: gif", robot=""))
    assert cli.main(["validate", str(m)]) == 2
    assert "output.image_format" in capsys.readouterr().err


def test_camera_pose_needs_a_chain_from_field_to_camera():
    eye = np.eye(4)
    t = eye.copy()
    t[0, 3] = 1.0
    T = detect_replay.camera_pose({"camera": ("body", t), "body": ("field", t)})
    assert np.allclose(T[:3, 3], [2.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="stops at 'body'"):
        detect_replay.camera_pose({"camera": ("body", eye)})
    with pytest.raises(ValueError, match="no transform chain"):
        detect_replay.camera_pose({"camera": ("body", eye), "body": ("camera", eye)})  # a loop


def _cut_after_first_detection(log: Path) -> int:
    """A byte offset inside the log that keeps the chunk holding the first /detection whole and cuts
    the next chunk in two. Chunks close on a wall-clock timer, so a fixed fraction of the file (once
    60 %) falls before or after that chunk depending on the machine's load. The chunk is found by its
    contents, not its time range: an image, its calibration and its detection carry one stamp, and a
    flush between them gave two chunks that range over it (the flaky failure of sessions 73–74)."""
    from mcap.reader import make_reader
    from mcap.records import Chunk, Message
    from mcap.stream_reader import StreamReader, breakup_chunk

    with open(log, "rb") as f:
        summary = make_reader(f).get_summary()
        f.seek(0)
        chunks = [r for r in StreamReader(f, emit_chunks=True).records if isinstance(r, Chunk)]
    det = {c.id for c in summary.channels.values() if c.topic == "/detection"}
    index = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert len(index) == len(chunks)
    i = next(k for k, ch in enumerate(chunks) if any(isinstance(r, Message) and r.channel_id in det for r in breakup_chunk(ch)))
    end = index[i].chunk_start_offset + index[i].chunk_length
    return index[i + 1].chunk_start_offset + index[i + 1].chunk_length // 2 if i + 1 < len(index) else end + 9


def test_a_truncated_log_is_said_to_be_one(runs, capsys, tmp_path):
    """A log cut short (a crash, a copy stopped half-way) replays what it holds, and says it is cut:
    the figures alone read as a whole run (found by a fuzzing sweep)."""
    whole = (runs["jpeg"] / "run.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: _cut_after_first_detection(runs["jpeg"] / "run.mcap")])
    rc, doc, out, err = _replay(capsys, cut, tmp_path, "--quiet")
    assert rc == 0 and "is truncated (crash?)" in err
    assert doc["log_notes"] and "truncated" in doc["log_notes"][0]
    assert 0 < doc["summary"]["detections"]
    rc, doc, out, err = _replay(capsys, runs["jpeg"], tmp_path, "--quiet")  # a whole log: no note
    assert rc == 0 and "note:" not in err and doc["log_notes"] == []


def test_text_from_a_log_cannot_drive_the_terminal():
    """Ids read back from a log are someone else's text: escape sequences and newlines are shown
    escaped, one line per detection (an id starting with ESC[2J cleared the screen)."""
    from capm_field.errors import terminal_safe
    from mission.detect_replay import Replayed, _line

    evil = "\x1b[2J\x1b[31mEVIL\x1b[0m\nW01"
    line = _line(Replayed(evil, 0, (1.0, 2.0), None, None))
    assert "\x1b" not in line and "\n" not in line and "\\x1b[2J" in line and "\\nW01" in line
    assert terminal_safe("W01 (ok)") == "W01 (ok)" and terminal_safe("a\x00b\tc") == "a\\x00b\\tc"


def test_cli_error_lines_are_escaped(capsys, tmp_path):
    bad = tmp_path / "x\x1b[2Jy.mcap"
    bad.write_bytes(b"not an mcap")
    rc = cli.main(["detect-replay", str(bad)])
    err = capsys.readouterr().err
    assert rc == 2 and "\x1b" not in err and "\\x1b[2J" in err and err.count("\n") == 1


def test_topics_carrying_another_message_are_skipped_with_a_note(capsys, tmp_path):
    """A hand-made or foreign log whose /detection, /tf, /plan, /camera/image, … carry another
    message, or our message's name with other fields (as `review` already skips): AttributeError /
    ValueError tracebacks, exit 1. Now skipped and counted, said in a note, exit 2."""
    from google.protobuf import descriptor_pb2
    from mcap.writer import Writer

    from mission.runlog_schema import descriptor_set_bytes, message_class

    T = descriptor_pb2.FieldDescriptorProto
    fd = descriptor_pb2.FileDescriptorProto(name="old.proto", package="capm.log", syntax="proto3")
    m = fd.message_type.add(name="Detection")  # no `pixel`: HasField("pixel") raised
    for i, name in enumerate(("target_id", "reason"), 1):
        m.field.add(name=name, number=i, type=T.TYPE_STRING, label=T.LABEL_OPTIONAL)
    other_detection = descriptor_pb2.FileDescriptorSet(file=[fd]).SerializeToString()
    ours = descriptor_set_bytes()
    energy = message_class("Energy")(total=1.0, target_id="W1").SerializeToString()
    detection = message_class("Detection")(target_id="W1", reason="no_plant").SerializeToString()
    cases = [(t, "capm.log.Energy", ours, energy) for t in
             ("/detection", "/tf", "/plan", "/regions", "/camera/image", "/camera/calibration", "/truth/mpoi")]
    cases.append(("/detection", "capm.log.Detection", other_detection, b"\x0a\x02W1\x12\x01x"))
    for topic, sname, sdata, payload in cases:
        p = tmp_path / "foreign.mcap"
        with p.open("wb") as f:
            w = Writer(f)
            w.start(profile="", library="test")
            odd = w.register_channel(topic, "protobuf", w.register_schema(sname, "protobuf", sdata))
            det = w.register_channel("/detection", "protobuf", w.register_schema("capm.log.Detection", "protobuf", ours))
            w.add_message(odd, 1, payload, 1)
            w.add_message(det, 2, detection, 2)  # one of ours after it: still read
            w.finish()
        rc = cli.main(["detect-replay", str(p), "--quiet"])
        err = capsys.readouterr().err
        assert rc == 2 and "1 message(s) skipped, not readable as this run log's" in err, (topic, err)
        assert "stored no images" in err, (topic, err)


def _with_images(src: Path, dst: Path, data: bytes, fmt: str) -> Path:
    """A copy of run log `src` whose every /camera/image carries `data` (as `fmt`)."""
    from mcap.reader import make_reader
    from mcap.writer import Writer
    from mcap_protobuf.decoder import DecoderFactory

    with src.open("rb") as f, dst.open("wb") as o:
        r = make_reader(f)
        w = Writer(o)
        w.start(profile="", library="test")
        summary = r.get_summary()
        schemas = {i: w.register_schema(s.name, s.encoding, s.data) for i, s in summary.schemas.items()}
        channels = {i: w.register_channel(c.topic, c.message_encoding, schemas.get(c.schema_id, 0), c.metadata)
                    for i, c in summary.channels.items()}
        for schema, ch, m in r.iter_messages(log_time_order=True):
            payload = m.data
            if ch.topic == "/camera/image":
                img = DecoderFactory().decoder_for(ch.message_encoding, schema)(m.data)
                img.data, img.format = data, fmt
                payload = img.SerializeToString()
            w.add_message(channels[ch.id], m.log_time, payload, m.publish_time, m.sequence)
        w.finish()
    return dst


def test_images_that_are_not_the_cameras_frames_are_said_not_decoded(runs, capsys, tmp_path):
    """A foreign or damaged log's image: empty (cv2.imdecode asserted: a traceback), a PNG of
    < 1 MB whose header declares 30 000 × 30 000 px (5.5 GB decoded before the detector saw it), or
    an image of another size than the calibration's camera (its ROI would be in other pixels):
    each detection is "not replayed" with the reason, from the header before decoding."""
    import struct
    import zlib

    import cv2

    def chunk(tag: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + tag + body + struct.pack(">I", zlib.crc32(tag + body))

    w = h = 30_000
    rows = zlib.compress(b"\x00" * ((w + 1) * 200), 9)  # (a valid stream need not hold every row: the header decides)
    bomb = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)) + chunk(b"IDAT", rows) + chunk(b"IEND", b"")
    small = cv2.imencode(".png", np.full((360, 640, 3), 90, np.uint8))[1].tobytes()
    for data, expect in ((b"", "its image is empty"),
                         (bomb, "its image is not a camera frame: 900 Mpx, over the 200 Mpx"),
                         (small, "its image is 640 × 360 px, the calibration's camera 1280 × 720")):
        log = _with_images(runs["png"] / "run.mcap", tmp_path / "odd.mcap", data, "png")
        rc = cli.main(["detect-replay", str(log)])
        out, err = capsys.readouterr()
        assert rc == 2 and "none of its 3 detections could be replayed" in err, err
        assert out.count(f"not replayed: {expect}") == 3, out



def test_json_naming_the_run_log_is_refused_and_the_log_kept(runs, capsys, tmp_path):
    """`--json run.mcap` (the log itself, or the run directory's) wrote the JSON over the mission
    log, exit 0; now refused before the replay."""
    import shutil

    run = tmp_path / "run"
    shutil.copytree(runs["jpeg"], run)
    before = (run / "run.mcap").read_bytes()
    for given in (run, run / "run.mcap"):
        rc = cli.main(["detect-replay", str(given), "--json", str(run / "." / "run.mcap")])
        out, err = capsys.readouterr()
        assert rc == 2 and "an input of this command; name another file" in err and out == "", err
    assert (run / "run.mcap").read_bytes() == before
