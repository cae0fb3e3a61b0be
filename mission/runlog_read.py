"""Read a run log back, including one cut short by a crash (no summary, no footer, torn tail).

A streaming read (`mcap.reader.NonSeekingReader`, in file order) needs no summary: it returns
every message of every complete chunk and stops at the first incomplete record. Chunk CRCs are
validated. Protobuf messages (ours and Foxglove's) are decoded from their embedded schemas with
mcap-protobuf-support; /robot_description (ROS 2 String, cdr) is decoded here.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

from mcap.exceptions import EndOfFile
from mcap.reader import NonSeekingReader
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


def decode_cdr_string(data: bytes) -> str:
    """std_msgs/String from CDR (encapsulation header + uint32 length incl. NUL + bytes)."""
    little = data[1] == 1
    (n,) = struct.unpack("<I" if little else ">I", data[4:8])
    return data[8 : 8 + n].rstrip(b"\x00").decode("utf-8")


def check_mcap(path: str | Path) -> Path:
    """The path of an existing file that starts with the MCAP magic, else UserError."""
    p = Path(path)
    if not p.is_file():
        raise UserError(f"run log not found: {p}")
    with p.open("rb") as f:
        head = f.read(len(MAGIC))
    if head != MAGIC:
        raise UserError(f"not an MCAP file: {p} (bad magic)")
    return p


def iter_run(path: str | Path, topics: set[str] | None = None, report: ReadReport | None = None) -> Iterator[RunMessage]:
    """Messages in file order. Stops quietly at a torn tail (see `report.error`)."""
    p = check_mcap(path)
    report = report if report is not None else ReadReport()
    factory = DecoderFactory()
    with p.open("rb") as f:
        reader = NonSeekingReader(f, validate_crcs=True)
        it = reader.iter_messages(topics=topics, log_time_order=False)
        while True:
            try:
                schema, channel, msg = next(it)
            except StopIteration:
                report.complete = True
                return
            except EndOfFile as e:
                report.error = f"truncated: {e or 'end of file inside a record'}"
                return
            except Exception as e:  # noqa: BLE001 - torn record, bad CRC, zstd error: a crash's tail
                report.error = f"{type(e).__name__}: {e}"
                return
            if channel.message_encoding == "cdr" and schema is not None and schema.name == "std_msgs/msg/String":
                data: Any = decode_cdr_string(msg.data)
            else:
                decoder = factory.decoder_for(channel.message_encoding, schema)
                data = decoder(msg.data) if decoder is not None else msg.data
            report.messages += 1
            yield RunMessage(channel.topic, msg.log_time, schema.name if schema else "", data)
