"""`capm-field review` and the run-log reader on hostile or damaged files: the log never
overwritten, an existing .rrd kept when a review fails, our schema names with other descriptors,
log times past int64, and damaged record headers in a cleanly closed file (found by an audit)."""

from __future__ import annotations

import os
import struct
from pathlib import Path

import pytest
from google.protobuf import descriptor_pb2
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from capm_field import cli
from mission import review
from mission.runlog_read import ReadReport, iter_run
from mission.runlog_schema import descriptor_set_bytes, message_class
from rerun_recording import rrd_contents

T0 = 1_700_000_000_000_000_000
N = 300  # Energy messages in the chunked test log: ~10 chunks of 1 KiB


def _write(path: Path, channels: list[tuple[str, str, bytes, list[tuple[int, bytes]]]], *, chunk_size: int = 1024,
           chunked: bool = True, compression: CompressionType = CompressionType.ZSTD) -> Path:
    """An MCAP of protobuf channels (topic, schema name, schema data, [(log_time, payload)])."""
    with path.open("wb") as f:
        w = Writer(f, chunk_size=chunk_size, compression=compression, use_chunking=chunked)
        w.start(profile="", library="test")
        for topic, sname, sdata, msgs in channels:
            cid = w.register_channel(topic, "protobuf", w.register_schema(sname, "protobuf", sdata))
            for t, payload in msgs:
                w.add_message(cid, t, payload, t)
        w.finish()
    return path


def _energy_log(path: Path, chunked: bool = True, compression: CompressionType = CompressionType.ZSTD) -> Path:
    energy = message_class("Energy")
    msgs = [(T0 + i * 10**6, energy(total=float(i), target_id="W1").SerializeToString()) for i in range(N)]
    return _write(path, [("/energy", "capm.log.Energy", descriptor_set_bytes(), msgs)], chunked=chunked, compression=compression)


def _chunks(path: Path) -> list:
    with path.open("rb") as f:
        return sorted(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)


def _damaged(src: Path, dst: Path, edits: dict[int, int]) -> Path:
    data = bytearray(src.read_bytes())
    for at, value in edits.items():
        data[at] = value
    dst.write_bytes(bytes(data))
    return dst


def _totals(path: Path) -> tuple[list[float], ReadReport]:
    rep = ReadReport()
    return [m.data.total for m in iter_run(path, report=rep)], rep


def _review(path: Path, rrd: Path, capsys) -> tuple[int, str]:
    rc = cli.main(["review", str(path), "--rrd", str(rrd)])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return rc, err


# ---- 1. the run log is never the output ---------------------------------------------------------
@pytest.mark.parametrize("how", ["same", "symlink", "run-dir", "dotdot"])
def test_rrd_naming_the_run_log_is_refused_and_the_log_kept(tmp_path, capsys, how):
    """`review RUN.mcap --rrd RUN.mcap` replaced the run log with a recording before failing."""
    run = tmp_path / "run1"
    run.mkdir()
    log = _energy_log(run / "run.mcap")
    before = log.read_bytes()
    if how == "symlink":
        (tmp_path / "link.rrd").symlink_to(log)
    arg, rrd = {
        "same": (log, log),
        "symlink": (log, tmp_path / "link.rrd"),
        "run-dir": (run, run / "run.mcap"),
        "dotdot": (run, run / ".." / "run1" / "run.mcap"),
    }[how]
    rc, err = _review(arg, rrd, capsys)
    assert rc == 2 and "is the run log being reviewed" in err and err.count("\n") == 1, err
    assert log.read_bytes() == before


# ---- 1b. a failed review leaves the previous .rrd ------------------------------------------------
def test_a_failed_review_keeps_the_previous_rrd_and_leaves_no_partial_file(tmp_path, capsys, monkeypatch):
    good = _energy_log(tmp_path / "good.mcap")
    out = tmp_path / "out.rrd"
    out.write_bytes(b"an earlier, good recording")
    # Rerun's importer refuses a schema that is no descriptor set (after our read succeeded)
    bad = _write(tmp_path / "bad.mcap", [
        ("/energy", "capm.log.Energy", descriptor_set_bytes(), [(T0, message_class("Energy")(total=1.0).SerializeToString())]),
        ("/plan", "capm.log.Plan", b"not a descriptor set", [(T0, b"\x00")]),
    ])
    with monkeypatch.context() as m:  # (a message our reader skips is no longer handed to Rerun)
        real = review.salvage
        m.setattr(review, "salvage", lambda src, dst, drop=(), keep=None, tick=None: real(src, dst))
        rc, err = _review(bad, out, capsys)
    assert rc == 2 and "Rerun cannot read" in err
    assert out.read_bytes() == b"an earlier, good recording"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.mcap", "good.mcap", "out.rrd"]

    def interrupted(*_a, **_k):
        raise KeyboardInterrupt

    with monkeypatch.context() as m:  # Ctrl-C while our overlays are being written
        m.setattr(review, "log_extras", interrupted)
        assert cli.main(["review", str(good), "--rrd", str(out)]) == 130
    assert out.read_bytes() == b"an earlier, good recording"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.mcap", "good.mcap", "out.rrd"]

    rc, err = _review(bad, tmp_path / "bad.rrd", capsys)  # the schema our reader skips is left out
    assert rc == 0 and "1 message(s) skipped" in err, err
    (tmp_path / "bad.rrd").unlink()
    rc, _ = _review(good, out, capsys)  # and a review that succeeds replaces it
    assert rc == 0 and out.read_bytes()[:4] != b"an e" and out.stat().st_size > 1000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.mcap", "good.mcap", "out.rrd"]


# ---- 4. our schema name, another descriptor ------------------------------------------------------
def _fds(message: str, fields: list[tuple[str, int]]) -> bytes:
    fd = descriptor_pb2.FileDescriptorProto(name="old.proto", package="capm.log", syntax="proto3")
    m = fd.message_type.add(name=message)
    for i, (name, ftype) in enumerate(fields, 1):
        m.field.add(name=name, number=i, type=ftype, label=descriptor_pb2.FieldDescriptorProto.LABEL_OPTIONAL)
    return descriptor_pb2.FileDescriptorSet(file=[fd]).SerializeToString()


def test_our_schema_name_with_another_descriptor_is_skipped_with_a_note(tmp_path, capsys):
    """capm.log.Plan without `troi`, capm.log.Energy with a string `total`: AttributeError /
    TypeError tracebacks in the drawing; now skipped and counted like other foreign messages."""
    T = descriptor_pb2.FieldDescriptorProto
    good = message_class("Energy")(total=2.0, target_id="W1").SerializeToString()
    p = _write(tmp_path / "old.mcap", [
        ("/plan", "capm.log.Plan", _fds("Plan", [("target_id", T.TYPE_STRING), ("planner", T.TYPE_STRING)]), [(T0, b"\x0a\x02W1\x12\x01c")]),
        ("/energy", "capm.log.Energy", _fds("Energy", [("total", T.TYPE_STRING)]), [(T0 + 1, b"\x0a\x03abc")]),
        ("/energy", "capm.log.Energy", descriptor_set_bytes(), [(T0 + 2, good)]),  # ours: drawn
    ])
    rc, err = _review(p, tmp_path / "o.rrd", capsys)
    assert rc == 0, err
    assert "2 message(s) skipped, not readable as this run log's" in err and "another descriptor" in err, err
    data = review.load_run(p)
    assert [m.total for _, m in data.messages["/energy"]] == [2.0] and not data.messages["/plan"]


# ---- 5. log times a timeline cannot hold ---------------------------------------------------------
@pytest.mark.parametrize("t", [2**64 - 1, 2**63])
def test_log_times_past_int64_are_skipped_with_a_note(tmp_path, capsys, t):
    """np.datetime64(2**63, "ns") raised OverflowError (a traceback) in the drawing."""
    e = message_class("Energy")(total=1.0, target_id="W1").SerializeToString()
    p = _write(tmp_path / "t.mcap", [("/energy", "capm.log.Energy", descriptor_set_bytes(), [(T0, e), (t, e)])])
    rc, err = _review(p, tmp_path / "o.rrd", capsys)
    assert rc == 0, err
    assert "1 message(s) skipped" in err and f"log_time {t} past 2**63 - 1 ns" in err, err


# ---- 6. an unknown opcode where a record is expected ----------------------------------------------
def test_a_chunk_whose_opcode_is_damaged_is_read_by_the_index_and_reported(tmp_path, capsys):
    """One flipped opcode byte (0x06 → 0xf9) made the reader skip the whole chunk as an unknown
    record: its messages lost, exit 0, no note. The summary's chunk index frames it."""
    clean = _energy_log(tmp_path / "clean.mcap")
    c = _chunks(clean)[3]
    bad = _damaged(clean, tmp_path / "bad.mcap", {c.chunk_start_offset: 0xF9})
    got, rep = _totals(bad)
    assert got == [float(i) for i in range(N)] and rep.complete and rep.error is None
    assert rep.repaired == 1 and "opcode 0xf9" in rep.damage_note()
    rc, err = _review(bad, tmp_path / "o.rrd", capsys)
    assert rc == 0 and "is damaged" in err and "damaged record header (opcode 0xf9" in err, err


def test_an_unknown_opcode_between_records_is_damage_and_the_shortfall_is_noted(tmp_path, capsys):
    """An unchunked file (no chunk index to frame it): the damaged record is skipped by its
    length, reported, and the count read is checked against the summary's message count."""
    clean = _energy_log(tmp_path / "clean.mcap", chunked=False)
    data = clean.read_bytes()
    pos, msgs = 8, []
    while data[pos] != 0x02:  # the footer
        if data[pos] == 0x05:
            msgs.append(pos)
        pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    bad = _damaged(clean, tmp_path / "bad.mcap", {msgs[100]: 0x55})
    got, rep = _totals(bad)
    assert got == [float(i) for i in range(N) if i != 100] and rep.complete
    note = rep.damage_note()
    assert note and "unknown record opcode 0x55" in note and f"{N - 1} of the {N} messages its summary lists" in note, note
    rc, err = _review(bad, tmp_path / "o.rrd", capsys)
    assert rc == 0 and f"{N - 1} of the {N} messages" in err, err


def test_an_unknown_opcode_inside_a_chunk_is_damage(tmp_path, capsys):
    """A chunk without a CRC (0: not checked) holding a record of unknown type: mcap's
    breakup_chunk skipped it silently. It is skipped by its length and reported."""
    clean = _energy_log(tmp_path / "clean.mcap", compression=CompressionType.NONE)
    c = _chunks(clean)[3]
    inner = c.chunk_start_offset + 9 + 8 + 8 + 8 + 4 + 4 + 8  # the chunk's first record (no compression name)
    assert clean.read_bytes()[inner] == 0x05  # a Message
    crc = c.chunk_start_offset + 9 + 24
    bad = _damaged(clean, tmp_path / "bad.mcap", {inner: 0x55, crc: 0, crc + 1: 0, crc + 2: 0, crc + 3: 0})
    got, rep = _totals(bad)
    assert len(got) == N - 1 and rep.complete
    note = rep.damage_note()
    assert note and "unknown record opcode 0x55 at byte 0 of the chunk" in note and f"{N - 1} of the {N} messages" in note, note
    rc, err = _review(bad, tmp_path / "o.rrd", capsys)
    assert rc == 0 and "is damaged" in err, err


# ---- 7. a corrupt chunk length in a complete file -------------------------------------------------
def test_a_corrupt_chunk_length_in_a_closed_file_is_damage_not_a_crash(tmp_path, capsys):
    """The length's high byte set: reported as "truncated (crash?)" and every later chunk lost,
    although the footer and summary list them all."""
    clean = _energy_log(tmp_path / "clean.mcap")
    c = _chunks(clean)[3]
    bad = _damaged(clean, tmp_path / "bad.mcap", {c.chunk_start_offset + 8: 0x7F})
    got, rep = _totals(bad)
    assert got == [float(i) for i in range(N)] and rep.complete and rep.error is None and rep.repaired == 1
    rc, err = _review(bad, tmp_path / "o.rrd", capsys)
    assert rc == 0 and "is damaged" in err and "truncated" not in err and "crash" not in err, err

    # length and contents damaged: that chunk is lost, the read goes on at the next indexed chunk
    inner = {c.chunk_start_offset + 8: 0x7F, c.chunk_start_offset + c.chunk_length - 10: 0x00}
    worse = _damaged(clean, tmp_path / "worse.mcap", inner)
    got, rep = _totals(worse)
    lost = {float(i) for i in range(N)} - set(got)
    assert lost and max(got) == N - 1 and rep.complete and rep.error is None
    assert got == sorted(got) and len(got) + len(lost) == N
    note = rep.damage_note()
    assert note and "1 damaged chunk" in note and f"{len(got)} of the {N} messages its summary lists" in note, note
    rc, err = _review(worse, tmp_path / "o.rrd", capsys)
    assert rc == 0 and "is damaged" in err and "crash" not in err, err

    # without a summary (a crash file) the same bytes are a torn tail, as before
    with clean.open("rb") as f:
        f.seek(-37, os.SEEK_END)
        summary_start = struct.unpack("<Q", f.read(17)[9:17])[0]
    crash = tmp_path / "crash.mcap"
    crash.write_bytes(bad.read_bytes()[:summary_start])
    got, rep = _totals(crash)
    assert not rep.complete and not rep.has_summary and rep.error.startswith("truncated")
    assert got == [float(i) for i in range(N)][: len(got)] and len(got) < N


# ---- 9. the summary section fails its CRC ---------------------------------------------------------
def test_a_closed_log_whose_summary_is_damaged_is_reviewed_from_its_data_section(tmp_path, capsys):
    """A Schema record of the summary section damaged (its CRC fails): every message is still in
    the data section; Rerun, handed the file as it is, refused it for the schema it read there."""
    src = bytearray(_energy_log(tmp_path / "good.mcap").read_bytes())
    footer = len(src) - 8 - 29  # footer record: opcode, length, summary_start, summary_offset_start, crc
    pos, = struct.unpack_from("<Q", src, footer + 9)
    while src[pos] != 0x03:  # the summary's first Schema record
        pos += 9 + struct.unpack_from("<Q", src, pos + 1)[0]
    src[pos + 9 + struct.unpack_from("<Q", src, pos + 1)[0] // 2] ^= 0x55
    bad = tmp_path / "damaged.mcap"
    bad.write_bytes(bytes(src))
    assert _totals(bad)[0] == [float(i) for i in range(N)]  # our reader: everything, from the data section
    rc, err = _review(bad, tmp_path / "out.rrd", capsys)
    assert rc == 0 and "no valid summary section" in err, err
    assert (tmp_path / "out.rrd").stat().st_size > 1000


# ---- 10. --rrd paths the file system refuses ------------------------------------------------------
def test_rrd_names_near_or_over_the_name_limit_and_special_files(tmp_path, capsys):
    good = _energy_log(tmp_path / "good.mcap")
    long_ok = tmp_path / ("a" * 245 + ".rrd")  # legal; a temporary name built from it was not
    rc, err = _review(good, long_ok, capsys)
    assert rc == 0 and long_ok.stat().st_size > 1000, err
    rc, err = _review(good, tmp_path / ("b" * 300 + ".rrd"), capsys)
    assert rc == 2 and "File name too long" in err and err.count("\n") == 1, err
    fifo = tmp_path / "pipe.rrd"
    os.mkfifo(fifo)
    rc, err = _review(good, fifo, capsys)
    assert rc == 2 and "not a regular file" in err and fifo.is_fifo(), err
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["good.mcap", long_ok.name, "pipe.rrd"])


def test_a_log_written_before_an_added_field_is_still_ours(tmp_path, capsys):
    """`Detection.roi_rim` came after the first run logs: a log whose schema lacks it (only it) is
    reviewed like any other (its detection drawn, no ROI on the image), not skipped as foreign."""
    from google.protobuf import timestamp_pb2

    from mission.runlog_schema import file_descriptor

    fd = file_descriptor()
    det = next(m for m in fd.message_type if m.name == "Detection")
    rim = next(f for f in det.field if f.name == "roi_rim")
    det.field.remove(rim)
    ts = descriptor_pb2.FileDescriptorProto()
    timestamp_pb2.DESCRIPTOR.CopyToProto(ts)
    old = descriptor_pb2.FileDescriptorSet(file=[ts, fd]).SerializeToString()
    msg = message_class("Detection")(target_id="W1", found=True, confidence=0.9)
    msg.pixel.x, msg.pixel.y = 320.0, 200.0
    p = _write(tmp_path / "old.mcap", [("/detection", "capm.log.Detection", old, [(T0, msg.SerializeToString())])])
    rc, err = _review(p, tmp_path / "o.rrd", capsys)
    assert rc == 0 and "skipped" not in err, err
    assert [m.pixel.x for _, m in review.load_run(p).messages["/detection"]] == [320.0]
    ents = rrd_contents(tmp_path / "o.rrd")
    assert "Points2D:positions" in ents["/camera/image/detection"]
    assert "LineStrips2D:strips" not in ents.get("/camera/image/roi", set())
    # a field that is not an added one is still required: without `pixel` the file is foreign
    pix = next(f for f in det.field if f.name == "pixel")
    det.field.remove(pix)
    worse = descriptor_pb2.FileDescriptorSet(file=[ts, fd]).SerializeToString()
    p2 = _write(tmp_path / "worse.mcap", [("/detection", "capm.log.Detection", worse, [(T0, b"\x12\x02W1")])])
    assert not review.load_run(p2).messages["/detection"]


def test_roi_rim_points_no_image_can_hold_are_left_out(tmp_path, capsys):
    """A foreign Detection whose `roi_rim` holds NaN, ∞ or 1e300 (past float32): reviewed, with
    the finite part of the rim drawn, not a crash or a warning in Rerun's conversion."""
    import warnings

    m = message_class("Detection")(target_id="W1", found=False)
    for x, y in [(1e300, 2.0), (float("nan"), 3.0), (10.0, 10.0), (20.0, 10.0), (20.0, 20.0), (float("inf"), 1.0)]:
        m.roi_rim.add(x=x, y=y)
    p = _write(tmp_path / "f.mcap", [("/detection", "capm.log.Detection", descriptor_set_bytes(), [(T0, m.SerializeToString())])])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rc, err = _review(p, tmp_path / "o.rrd", capsys)
    assert rc == 0, err
    ents = rrd_contents(tmp_path / "o.rrd")
    assert "LineStrips2D:strips" in ents["/camera/image/roi"]


# ---- 9. payloads Rerun's importer cannot decode ---------------------------------------------------
def _foxglove_log(path: Path, n: int = 12) -> Path:
    """A foxglove-sdk log: n /tf FrameTransforms (field→body) and n /log lines."""
    import foxglove
    from foxglove.channels import FrameTransformsChannel, LogChannel
    from foxglove.messages import FrameTransform, FrameTransforms, Log, LogLevel, Quaternion, Vector3

    ctx = foxglove.Context()
    w = foxglove.open_mcap(str(path), allow_overwrite=True, context=ctx)
    tf, log = FrameTransformsChannel("/tf", context=ctx), LogChannel("/log", context=ctx)
    for i in range(n):
        tf.log(FrameTransforms(transforms=[FrameTransform(parent_frame_id="field", child_frame_id="body",
                                                          translation=Vector3(x=0.1 * i, y=0.0, z=0.0),
                                                          rotation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))]), log_time=T0 + i * 10**7)
        log.log(Log(message=f"line {i}", level=LogLevel.Info), log_time=T0 + i * 10**7)
    w.close()
    return path


def _garbled(src: Path, dst: Path, topic: str) -> Path:
    """A copy whose `topic` payloads are bytes no protobuf decoder takes."""
    with src.open("rb") as f, dst.open("wb") as g:
        r = make_reader(f)
        w = Writer(g)
        w.start(profile="", library="test")
        sids: dict[int, int] = {}
        cids: dict[int, int] = {}
        for schema, ch, msg in r.iter_messages():
            if schema.id not in sids:
                sids[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if ch.id not in cids:
                cids[ch.id] = w.register_channel(ch.topic, ch.message_encoding, sids[schema.id])
            data = b"\x0f\xff\xff" + msg.data[:20] if ch.topic == topic else msg.data
            w.add_message(cids[ch.id], msg.log_time, data, msg.publish_time)
        w.finish()
    return dst


def test_payloads_rerun_cannot_decode_are_left_out_and_an_unfinished_recording_is_refused(tmp_path, capsys, monkeypatch):
    """A log whose /tf payloads are all garbage: Rerun's importer logged errors and its file sink then
    failed to finish the recording (no footer; the viewer's reader refuses it), with exit 0 and
    "wrote". Now the messages our reader skips are not handed to the importer, and a recording Rerun
    did not finish is an error that leaves the previous .rrd as it was."""
    from rerun.chunk import RrdReader

    bad = _garbled(_foxglove_log(tmp_path / "good.mcap"), tmp_path / "bad.mcap", "/tf")
    out = tmp_path / "out.rrd"
    rc = cli.main(["review", str(bad), "--rrd", str(out)])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert "12 message(s) skipped" in cap.err and "(12 messages; 12 skipped" in cap.out, cap
    assert RrdReader(out).store() is not None  # finished: its manifest reads
    assert "TextLog:text" in rrd_contents(out)["/log"]

    out.write_bytes(b"an earlier recording")
    with monkeypatch.context() as m:  # hand the importer everything again: Rerun cannot finish
        real = review.salvage
        m.setattr(review, "salvage", lambda src, dst, drop=(), keep=None, tick=None: real(src, dst))
        rc, err = _review(bad, out, capsys)
    assert rc == 2 and "Rerun did not finish the recording (no footer" in err and "nothing written" in err, err
    assert out.read_bytes() == b"an earlier recording"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.mcap", "good.mcap", "out.rrd"]


def test_a_robot_description_whose_length_overruns_its_payload_is_skipped(tmp_path, capfd):
    """A CDR String whose length field runs past the payload read as "" here, while Rerun's importer
    logged `failed to deserialize CDR message` and review said "wrote", no note."""
    from mission.runlog_read import decode_cdr_string

    with pytest.raises(ValueError):
        decode_cdr_string(b"\x00\x01\x00\x00\xff\xff\xff\x7f")
    assert decode_cdr_string(b"\x00\x01\x00\x00\x03\x00\x00\x00ab\x00") == "ab"
    p = tmp_path / "urdf.mcap"
    with p.open("wb") as f:
        w = Writer(f)
        w.start(profile="", library="test")
        cid = w.register_channel("/robot_description", "cdr", w.register_schema("std_msgs/msg/String", "ros2msg", b"string data"))
        w.add_message(cid, T0, b"\x00\x01\x00\x00\xff\xff\xff\x7f", T0)
        w.add_message(cid, T0 + 1, b"\x00\x01\x00\x00\x03\x00\x00\x00ab\x00", T0 + 1)
        w.finish()
    rc = cli.main(["review", str(p), "--rrd", str(tmp_path / "o.rrd")])
    err = capfd.readouterr().err
    assert rc == 0 and "1 message(s) skipped" in err and "failed to deserialize" not in err, err
