"""Read a run log back, including one cut short by a crash (no summary, no footer, torn tail).

A streaming read (`mcap.stream_reader.StreamReader`, what `NonSeekingReader` uses, in file
order) needs no summary: it returns every message of every complete chunk and stops at the
first incomplete record. Chunk CRCs are validated: a chunk that fails (a bad sector of the
robot's disk) is skipped and counted, and the chunks after it are still read. Protobuf
messages (ours and Foxglove's) are decoded from their embedded schemas with
mcap-protobuf-support; /robot_description (ROS 2 String, cdr) is decoded here. `salvage`
copies the readable part into a finalised file.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

from mcap.exceptions import EndOfFile, RecordLengthLimitExceeded
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer
from mcap_protobuf.decoder import DecoderFactory

from capm_field.errors import UserError

MAGIC = b"\x89MCAP0\r\n"


@dataclass(frozen=True)
class RunMessage:
    topic: str
    log_time: int
    schema: str
    data: Any  # decoded protobuf message, or str for /robot_description


@dataclass
class ReadReport:
    messages: int = 0
    complete: bool = False  # the file ended with a footer (closed cleanly)
    error: str | None = None  # why reading stopped early (a crash-truncated tail)
    bad_chunks: int = 0  # chunks skipped because their CRC or compression was damaged
    orphans: int = 0  # messages skipped because their channel was defined in a skipped chunk
    damage: str | None = None  # the first skipped chunk's problem
    undecodable: int = 0  # messages skipped because their payload or schema did not decode
    undecodable_note: str | None = None  # the first of them: topic and problem

    def damage_note(self) -> str | None:
        """One line on what was skipped in the middle of the file, or None."""
        if not self.bad_chunks:
            return None
        return (f"{self.bad_chunks} damaged chunk(s) skipped ({self.damage}); "
                f"{self.orphans} later message(s) on channels defined there skipped too")

    def skip(self, topic: str, why: str) -> None:
        """Count a message that is not read (undecodable, or not what its topic should carry)."""
        self.undecodable += 1
        self.undecodable_note = self.undecodable_note or f"{topic}: {why}"


def decode_cdr_string(data: bytes) -> str:
    """std_msgs/String from CDR (encapsulation header + uint32 length incl. NUL + bytes)."""
    little = data[1] == 1
    (n,) = struct.unpack("<I" if little else ">I", data[4:8])
    return data[8 : 8 + n].rstrip(b"\x00").decode("utf-8")


def check_mcap(path: str | Path) -> Path:
    """The path of an existing file that starts with the MCAP magic, else UserError. A run's
    directory (holding run.mcap) stands for its log."""
    p = Path(path)
    if p.is_dir() and (p / "run.mcap").is_file():
        p = p / "run.mcap"
    elif p.is_dir():
        raise UserError(f"{p} is a directory without a run.mcap")
    if not p.is_file():
        raise UserError(f"run log not found: {p}")
    with p.open("rb") as f:
        head = f.read(len(MAGIC))
    if head != MAGIC:
        raise UserError(f"not an MCAP file: {p} (bad magic)")
    return p


def _iter_records(path: Path, report: ReadReport) -> Iterator[Schema | Channel | Message | Metadata]:
    """Schema, Channel, Message and Metadata records in file order, up to a torn tail."""
    with path.open("rb") as f:
        # chunks are broken up here, each on its own, so one damaged chunk does not end the read
        # (the data-section CRC over all of them is then not checked: the chunk CRCs cover it)
        records = StreamReader(f, emit_chunks=True).records
        while True:
            try:
                rec = next(records)
            except StopIteration:
                report.complete = True
                return
            except RecordLengthLimitExceeded:
                # foxglove-sdk writes a chunk's length when the chunk closes: a kill leaves 2⁶⁴−1.
                report.error = "truncated: an unfinished chunk at the end (the writer stopped mid-chunk)"
                return
            except EndOfFile as e:
                report.error = f"truncated: {str(e) or 'the file ends inside a record'}"
                return
            except Exception as e:  # noqa: BLE001 - torn record, bad CRC, zstd error: a crash's tail
                report.error = f"{type(e).__name__}: {e}"
                return
            if isinstance(rec, Chunk):
                try:
                    inner = breakup_chunk(rec, validate_crc=True)
                except Exception as e:  # noqa: BLE001 - bad CRC, corrupt zstd/lz4, torn inner record
                    report.bad_chunks += 1
                    report.damage = report.damage or f"{type(e).__name__}: {e}"
                    continue
                yield from (r for r in inner if isinstance(r, (Schema, Channel, Message, Metadata)))
            elif isinstance(rec, (Schema, Channel, Message, Metadata)):
                yield rec


def _summary_tables(path: Path) -> tuple[dict[int, Schema], dict[int, Channel]]:
    """Schemas and channels from the summary section of a cleanly closed file (empty for a
    crash file): they repeat the records inside the chunks, so messages of a channel whose
    record sat in a damaged chunk can still be decoded."""
    try:
        with path.open("rb") as f:
            summary = make_reader(f).get_summary()
    except Exception:  # noqa: BLE001 - no footer or a damaged summary: the chunks' records only
        return {}, {}
    if summary is None:
        return {}, {}
    return dict(summary.schemas), dict(summary.channels)


def _iter_raw(path: Path, topics: set[str] | None, report: ReadReport) -> Iterator[tuple[Schema | None, Channel, Message]]:
    schemas, channels = _summary_tables(path)
    for rec in _iter_records(path, report):
        if isinstance(rec, Schema):
            schemas[rec.id] = rec
        elif isinstance(rec, Channel):
            channels[rec.id] = rec
        elif isinstance(rec, Message):
            ch = channels.get(rec.channel_id)
            if ch is None:  # its Channel record was in a damaged chunk
                report.orphans += 1
                continue
            if topics is None or ch.topic in topics:
                yield schemas.get(ch.schema_id), ch, rec


def iter_run(path: str | Path, topics: set[str] | None = None, report: ReadReport | None = None) -> Iterator[RunMessage]:
    """Decoded messages in file order. Stops quietly at a torn tail (see `report.error`)."""
    p = check_mcap(path)
    report = report if report is not None else ReadReport()
    factory = DecoderFactory()
    decoders: dict[int, Callable[[bytes], Any] | None | Exception] = {}
    for schema, channel, msg in _iter_raw(p, topics, report):
        # a damaged or foreign message (bad payload, schema that is no descriptor) is skipped and
        # counted, like a damaged chunk: the rest of the run is still worth reading
        try:
            if channel.message_encoding == "cdr" and schema is not None and schema.name == "std_msgs/msg/String":
                data: Any = decode_cdr_string(msg.data)
            else:
                if channel.id not in decoders:
                    try:
                        decoders[channel.id] = factory.decoder_for(channel.message_encoding, schema)
                    except Exception as e:  # noqa: BLE001 - remembered: one failure per channel
                        decoders[channel.id] = e
                dec = decoders[channel.id]
                if isinstance(dec, Exception):
                    raise dec
                data = dec(msg.data) if dec is not None else msg.data
        except Exception as e:  # noqa: BLE001 - protobuf DecodeError, struct/Index/Unicode errors
            report.skip(channel.topic, f"{type(e).__name__}: {' '.join(str(e).split())[:120]}")
            continue
        report.messages += 1
        yield RunMessage(channel.topic, msg.log_time, schema.name if schema else "", data)


def salvage(src: str | Path, dst: str | Path) -> ReadReport:
    """Copy every readable record of a (crash-truncated) log into a finalised MCAP at `dst`.

    Bytes are copied, not re-encoded. Tools that insist on a summary and complete message
    indexes (Rerun's importer drops channels whose index was torn) read the copy instead.
    """
    p = check_mcap(src)
    report = ReadReport()
    with open(dst, "wb") as out:
        w = Writer(out, compression=CompressionType.ZSTD)
        w.start(profile="", library="capm-field salvage")
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}
        schemas, channels = _summary_tables(p)
        for rec in _iter_records(p, report):
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, Metadata):
                w.add_metadata(rec.name, dict(rec.metadata))
            elif isinstance(rec, Message) and rec.channel_id not in channels:
                report.orphans += 1
            elif isinstance(rec, Message):
                if rec.channel_id not in channel_ids:
                    ch = channels[rec.channel_id]
                    sid = 0
                    if ch.schema_id in schemas:
                        if ch.schema_id not in schema_ids:
                            s = schemas[ch.schema_id]
                            schema_ids[ch.schema_id] = w.register_schema(s.name, s.encoding, s.data)
                        sid = schema_ids[ch.schema_id]
                    channel_ids[rec.channel_id] = w.register_channel(ch.topic, ch.message_encoding, sid, dict(ch.metadata))
                w.add_message(channel_ids[rec.channel_id], rec.log_time, rec.data, rec.publish_time, rec.sequence)
                report.messages += 1
        w.finish()
    return report
