"""Read a run log back, including one cut short by a crash (no summary, no footer, torn tail).

A streaming read in file order (the framing of mcap's `StreamReader`, which `NonSeekingReader`
uses) needs no summary: it returns every message of every complete chunk and stops at the first
incomplete record. Chunk CRCs are validated: a chunk that fails (a bad sector of the robot's
disk) is skipped and counted, and the chunks after it are still read. In a cleanly closed file
(a summary whose CRC checks out) a damaged record header is damage, not a crash's tail: the
summary's chunk indexes say where each chunk starts, and the messages read are checked against
its message count. Protobuf messages (ours and Foxglove's) are decoded from their embedded
schemas with mcap-protobuf-support; /robot_description (ROS 2 String, cdr) is decoded here.
`salvage` copies the readable part into a finalised file.
"""

from __future__ import annotations

import bisect
import os
import struct
import zlib
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import Any, BinaryIO, Callable, Collection, Iterator

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, ChunkIndex, Message, Metadata, Schema
from mcap.reader import make_reader
from mcap.stream_reader import get_chunk_data_stream
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
    record: int = -1  # its Message record's place among the file's (0-based, read order; `salvage(drop=)`)


@dataclass
class ReadReport:
    messages: int = 0
    complete: bool = False  # the file ended with a footer (closed cleanly)
    has_summary: bool = False  # a summary section whose CRC checked out: the file was closed
    error: str | None = None  # why reading stopped early (a crash-truncated tail)
    bad_chunks: int = 0  # damaged stretches skipped: a chunk's CRC or compression, an unknown opcode, a bad length
    orphans: int = 0  # messages skipped because their channel was defined in a skipped chunk
    damage: str | None = None  # the first skipped chunk's problem
    repaired: int = 0  # chunks with a damaged record header, read whole (framed by the chunk index or their own sizes)
    repair: str | None = None  # the first of them
    undecodable: int = 0  # messages skipped because their payload or schema did not decode
    undecodable_note: str | None = None  # the first of them: topic and problem
    skipped_records: set[int] = field(default_factory=set)  # their places (`RunMessage.record`)
    records: int = 0  # Message records read, decodable or not
    expected_messages: int | None = None  # the summary's statistics.message_count (None: no summary)

    @property
    def lost(self) -> int:
        """Messages the summary lists that the read did not reach (0 without a summary)."""
        return max(0, (self.expected_messages or 0) - self.records)

    @property
    def damaged(self) -> bool:
        return bool(self.bad_chunks or self.repaired or self.lost)

    def damage_note(self) -> str | None:
        """One line on what was skipped or repaired in the middle of the file, or None."""
        parts = []
        if self.bad_chunks:
            parts.append(f"{self.bad_chunks} damaged chunk(s) or record(s) skipped ({self.damage}); "
                         f"{self.orphans} later message(s) on channels defined there skipped too")
        if self.repaired:
            parts.append(f"{self.repaired} chunk(s) with a damaged record header read whole ({self.repair})")
        if self.lost:  # damage that left no other trace still shows as a shortfall
            parts.append(f"{self.records} of the {self.expected_messages} messages its summary lists were read ({self.lost} lost)")
        return "; ".join(parts) or None

    def notes(self, path: Path | str) -> list[str]:
        """What a reader of `path` should be told about this read: a truncated or damaged file,
        messages skipped (one line each; none for a clean read). `capm-field review` and
        `detect-replay` print them."""
        out = []
        if self.error and not self.has_summary:
            out.append(f"{path} is truncated (crash?); showing what was complete: {self.error}")
        elif self.error:  # a closed file (valid summary) whose read stopped early: damage, not a crash
            out.append(f"{path} is damaged; showing what was readable: {self.error}")
        elif self.complete and not self.has_summary:  # closed, but its summary failed its CRC (or was never written)
            out.append(f"{path} has no valid summary section; showing what its data section holds")
        if self.damage_note():
            out.append(f"{path} is damaged: {self.damage_note()}")
        if self.undecodable:
            out.append(f"{self.undecodable} message(s) skipped, not readable as this run log's (first: {self.undecodable_note})")
        return out

    def skip(self, topic: str, why: str, record: int | None = None) -> None:
        """Count a message that is not read (undecodable, or not what its topic should carry);
        `record`: its place, so that `salvage` can leave it out of a copy for other readers."""
        self.undecodable += 1
        if record is not None:
            self.skipped_records.add(record)
        self.undecodable_note = self.undecodable_note or f"{topic}: {why}"


def decode_cdr_string(data: bytes) -> str:
    """std_msgs/String from CDR (encapsulation header + uint32 length incl. NUL + bytes)."""
    little = data[1] == 1
    (n,) = struct.unpack("<I" if little else ">I", data[4:8])
    if 8 + n > len(data):  # (a slice would read it as shorter text; Rerun's importer refuses it)
        raise ValueError(f"CDR string of {n} bytes in a payload of {len(data)}")
    return data[8 : 8 + n].rstrip(b"\x00").decode("utf-8")


def check_mcap(path: str | Path) -> Path:
    """The path of an existing file that starts with the MCAP magic, else UserError. A run's
    directory (holding run.mcap) stands for its log."""
    p = Path(path)
    if p.is_dir() and (p / "run.mcap").is_file():
        p = p / "run.mcap"
    elif p.is_dir():
        raise UserError(f"{p} is a directory without a run.mcap")
    if p.exists() and not p.is_file():  # a FIFO, a device: reading one would block or never end
        raise UserError(f"not a regular file: {p}")
    if not p.is_file():
        raise UserError(f"run log not found: {p}")
    with p.open("rb") as f:
        head = f.read(len(MAGIC))
    if head != MAGIC:
        raise UserError(f"not an MCAP file: {p} (bad magic)")
    return p


_KNOWN_OPCODES = {int(o) for o in Opcode}
_RECORD_SIZE_LIMIT = 4 * 2**30  # what mcap's StreamReader refuses too: a larger length is a torn or damaged one
_UNFINISHED = 2**64 - 1  # the length foxglove-sdk leaves on a chunk it never closed (a kill)
_FOOTER_LEN = 1 + 8 + 8 + 8 + 4  # opcode, length, summary_start, summary_offset_start, summary_crc


@dataclass
class _Summary:
    """The summary section of a cleanly closed file, once its CRC (or, without one, its offsets)
    checked out: trusted to say where each chunk starts when a record header is damaged."""

    schemas: dict[int, Schema]
    channels: dict[int, Channel]
    chunks: dict[int, ChunkIndex]  # chunk_start_offset -> index
    message_count: int | None


def _read_summary(path: Path) -> _Summary | None:
    """The file's summary section, or None (a crash file, no summary, or a damaged one)."""
    try:
        with path.open("rb") as f:
            size = os.fstat(f.fileno()).st_size
            if size < len(MAGIC) + _FOOTER_LEN + len(MAGIC):
                return None
            f.seek(size - _FOOTER_LEN - len(MAGIC))
            tail = f.read(_FOOTER_LEN + len(MAGIC))
            if tail[-len(MAGIC):] != MAGIC or tail[0] != Opcode.FOOTER:
                return None
            summary_start, _, summary_crc = struct.unpack("<QQI", tail[9:_FOOTER_LEN])
            data_end = size - _FOOTER_LEN - len(MAGIC)
            if not len(MAGIC) <= summary_start <= data_end:
                return None
            if summary_crc:  # covers the summary section and the footer up to the CRC itself
                f.seek(summary_start)
                if zlib.crc32(f.read(size - len(MAGIC) - 4 - summary_start)) != summary_crc:
                    return None
            f.seek(0)
            summary = make_reader(f).get_summary()
    except Exception:  # noqa: BLE001 - a damaged summary: the chunks' own records only
        return None
    if summary is None:
        return None
    chunks = {c.chunk_start_offset: c for c in summary.chunk_indexes
              if len(MAGIC) <= c.chunk_start_offset and c.chunk_length > 9 and c.chunk_start_offset + c.chunk_length <= summary_start}
    count = summary.statistics.message_count if summary.statistics is not None else None
    return _Summary(dict(summary.schemas), dict(summary.channels), chunks, count)


def _breakup_chunk(chunk: Chunk) -> tuple[list[Schema | Channel | Message], str | None]:
    """A chunk's records, and the first problem met in it (None: all read). Unlike mcap's
    `breakup_chunk`, which skips them silently, a record of another type (a chunk holds only
    Schema, Channel and Message records, MCAP spec) or an unreadable one is damage: skipped by
    its length and reported; a length past the chunk's end ends the chunk."""
    stream, size = get_chunk_data_stream(chunk, validate_crc=True)  # raises on a bad CRC or codec
    data = stream.read(size) if size else b""
    out: list[Schema | Channel | Message] = []
    problem: str | None = None
    pos = 0
    while pos < size:
        if pos + 9 > size:
            return out, problem or f"a torn record header at byte {pos} of the chunk"
        opcode, length = struct.unpack_from("<BQ", data, pos)
        if pos + 9 + length > size:
            return out, problem or f"a record at byte {pos} of the chunk runs past its end (length {length})"
        try:
            rec = _parse(opcode, data[pos + 9 : pos + 9 + length])
        except Exception as e:  # noqa: BLE001 - a torn field, bad UTF-8
            rec, why = None, f"an unreadable record (opcode 0x{opcode:02x}) at byte {pos} of the chunk: {type(e).__name__}: {e}"
        else:
            why = f"unknown record opcode 0x{opcode:02x} at byte {pos} of the chunk"
        if isinstance(rec, (Schema, Channel, Message)):
            out.append(rec)
        else:
            problem = problem or why
        pos += 9 + length
    return out, problem


def _parse(opcode: int, body: bytes) -> Schema | Channel | Message | Metadata | Chunk | None:
    """One record from its body; None for a known record type not needed here (indexes, ...)."""
    stream = ReadDataStream(BytesIO(body))
    if opcode == Opcode.MESSAGE:
        if len(body) < 22:
            raise ValueError(f"a Message record of {len(body)} bytes (< 22)")
        return Message.read(stream, len(body))
    reader = {Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel, Opcode.METADATA: Metadata, Opcode.CHUNK: Chunk}.get(opcode)
    return reader.read(stream) if reader else None


def _chunk_length(f: BinaryIO, pos: int, size: int) -> int | None:
    """The body length a Chunk record at `pos` has by its own fields (start, end, size, CRC,
    compression, data length), or None when they do not fit in the file."""
    fixed = pos + 9 + 8 + 8 + 8 + 4
    if fixed + 4 > size:
        return None
    f.seek(fixed)
    (clen,) = struct.unpack("<I", f.read(4))
    if fixed + 4 + clen + 8 > size:
        return None
    f.seek(fixed + 4 + clen)
    (dlen,) = struct.unpack("<Q", f.read(8))
    n = 8 + 8 + 8 + 4 + 4 + clen + 8 + dlen
    return n if pos + 9 + n <= size else None


def _iter_records(path: Path, report: ReadReport, summary: _Summary | None) -> Iterator[Schema | Channel | Message | Metadata]:
    """Schema, Channel, Message and Metadata records in file order, up to a torn tail.

    A record that cannot be read (unknown opcode, a length past the end of the file, torn
    fields) is damage, counted in `report`. With a valid summary the file is known to be
    complete, so such a record is damage, not a crash's tail: the read goes on at the next chunk
    the summary's chunk indexes list, and a chunk whose header alone is damaged is read by its
    index. Without a summary a length past the end is a torn tail and ends the read."""
    chunks = summary.chunks if summary else {}
    starts = sorted(chunks)
    report.expected_messages = summary.message_count if summary else None
    report.has_summary = summary is not None
    in_damage = False  # one damaged stretch counts once, however many bad records it holds

    def damaged(why: str) -> None:
        nonlocal in_damage
        if not in_damage:
            report.bad_chunks += 1
            report.damage = report.damage or why
        in_damage = True

    with path.open("rb") as f:
        size = os.fstat(f.fileno()).st_size
        pos = len(MAGIC)
        while True:
            f.seek(pos)
            head = f.read(9)
            if len(head) < 9:
                if in_damage and summary:
                    report.error = f"damaged: nothing readable from offset {pos} to the end"
                else:
                    report.error = "truncated: the file ends inside a record" if head else "truncated: the file ends without a footer"
                return
            opcode, length = struct.unpack("<BQ", head)
            k = bisect.bisect_right(starts, pos)
            nxt = starts[k] if k < len(starts) else None  # where to resume after damage here
            idx = chunks.get(pos)
            repaired = None  # set when the header is damaged but the chunk can still be framed
            if idx is not None and (opcode != Opcode.CHUNK or 9 + length != idx.chunk_length):
                # the chunk index says where this chunk ends; its CRC and sizes say whether it is intact
                repaired = f"chunk at offset {pos}: damaged record header (opcode 0x{opcode:02x}, length {length}), framed by the summary's chunk index"
                opcode, length = int(Opcode.CHUNK), idx.chunk_length - 9
            elif idx is None and opcode == Opcode.CHUNK and pos + 9 + length <= size:
                # a length shorter than the chunk's own size fields: they frame it (as mcap's
                # StreamReader does, which reads the fields and ignores the length); its CRC checks it
                own = _chunk_length(f, pos, size)
                if own is not None and own > length:
                    repaired = f"chunk at offset {pos}: record length {length} shorter than its contents ({own}), framed by its own size fields"
                    length = own
            end = pos + 9 + length
            if opcode not in _KNOWN_OPCODES or end > size or length > _RECORD_SIZE_LIMIT:
                why = (f"unknown record opcode 0x{opcode:02x} at offset {pos}" if opcode not in _KNOWN_OPCODES
                       else f"a record at offset {pos} (opcode 0x{opcode:02x}) runs past the end of the file (length {length})")
                if summary is not None and nxt is not None:
                    damaged(why)
                    pos = nxt
                elif opcode not in _KNOWN_OPCODES and end <= size:
                    damaged(why)  # its length frames it: skip just this record
                    pos = end
                elif summary is not None:
                    damaged(why)
                    report.error = f"damaged: {why}; no chunk after it is indexed"
                    return
                elif length >= _UNFINISHED or length > _RECORD_SIZE_LIMIT:
                    # foxglove-sdk writes a chunk's length when the chunk closes: a kill leaves 2⁶⁴−1.
                    report.error = "truncated: an unfinished chunk at the end (the writer stopped mid-chunk)"
                    return
                else:
                    report.error = f"truncated: the file ends inside a record (offset {pos}, length {length})"
                    return
                continue
            f.seek(pos + 9)
            body = f.read(length)
            try:
                rec = _parse(opcode, body)
                if repaired and idx is not None and not (
                        isinstance(rec, Chunk) and len(rec.data) == idx.compressed_size
                        and rec.uncompressed_size == idx.uncompressed_size and rec.compression == idx.compression):
                    raise ValueError("not the chunk its index describes")
            except Exception as e:  # noqa: BLE001 - torn fields, bad UTF-8: a damaged record
                damaged(f"{repaired or f'an unreadable record (opcode 0x{opcode:02x}) at offset {pos}'}: {type(e).__name__}: {e}")
                pos = nxt if summary is not None and nxt is not None else end
                continue
            if isinstance(rec, Chunk):
                try:
                    inner, problem = _breakup_chunk(rec)
                except Exception as e:  # noqa: BLE001 - bad CRC, corrupt zstd/lz4
                    damaged(f"{repaired + ': ' if repaired else ''}{type(e).__name__}: {e}")
                    pos = end
                    continue
                if repaired:  # framed anew and intact (CRC, and the index's sizes): nothing lost
                    report.repaired += 1
                    report.repair = report.repair or repaired
                in_damage = False
                if problem:
                    damaged(f"chunk at offset {pos}: {problem}")
                    in_damage = False  # the next record is framed by this chunk's own length
                for r in inner:
                    report.records += isinstance(r, Message)
                    yield r
            elif opcode == Opcode.FOOTER:
                f.seek(end)
                if f.read(len(MAGIC)) != MAGIC:
                    report.error = "truncated: the file ends inside its closing magic"
                    return
                report.complete = True
                return
            else:
                in_damage = False
                if rec is not None:
                    report.records += isinstance(rec, Message)
                    yield rec
            pos = end


def _tables(summary: _Summary | None) -> tuple[dict[int, Schema], dict[int, Channel]]:
    """The schemas and channels to start a read with (the records met in the chunks are added):
    a closed file's summary repeats them, so messages of a channel whose record sat in a damaged
    chunk can still be decoded; a crash file has none."""
    return (dict(summary.schemas), dict(summary.channels)) if summary else ({}, {})


def _iter_raw(path: Path, topics: set[str] | None, report: ReadReport) -> Iterator[tuple[Schema | None, Channel, Message]]:
    summary = _read_summary(path)
    schemas, channels = _tables(summary)
    for rec in _iter_records(path, report, summary):
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
            report.skip(channel.topic, f"{type(e).__name__}: {' '.join(str(e).split())[:120]}", report.records - 1)
            continue
        report.messages += 1
        yield RunMessage(channel.topic, msg.log_time, schema.name if schema else "", data, report.records - 1)


def salvage(src: str | Path, dst: str | Path, drop: Collection[int] = (), keep: Collection[int] | None = None,
            tick: Callable[[], object] | None = None) -> ReadReport:
    """Copy every readable record of a (crash-truncated) log into a finalised MCAP at `dst`.

    Bytes are copied, not re-encoded. Tools that insist on a summary and complete message
    indexes (Rerun's importer drops channels whose index was torn) read the copy instead.
    `drop`: Message records left out, by place (`RunMessage.record`, `ReadReport.skipped_records`):
    payloads our reader could not decode, which stop Rerun's importer from finishing a recording.
    `keep`: if given, only these Message records are copied (a part of a long run, `review --targets`);
    the others are neither copied nor counted. `tick()` is called for every Message record read (progress).
    """
    p = check_mcap(src)
    report = ReadReport()
    with open(dst, "wb") as out:
        w = Writer(out, compression=CompressionType.ZSTD)
        w.start(profile="", library="capm-field salvage")
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}
        summary = _read_summary(p)
        schemas, channels = _tables(summary)
        for rec in _iter_records(p, report, summary):
            if tick is not None and isinstance(rec, Message):
                tick()
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, Metadata):
                w.add_metadata(rec.name, dict(rec.metadata))
            elif isinstance(rec, Message) and rec.channel_id not in channels:
                report.orphans += 1
            elif isinstance(rec, Message) and report.records - 1 in drop:
                report.undecodable += 1
            elif isinstance(rec, Message) and keep is not None and report.records - 1 not in keep:
                continue
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
