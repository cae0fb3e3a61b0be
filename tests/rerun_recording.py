"""What a Rerun recording (.rrd) holds, for the review tests."""

from __future__ import annotations

from pathlib import Path

from rerun.chunk import RrdReader


def rrd_contents(path: Path) -> dict[str, set[str]]:
    """entity path -> component names, over the recording in the .rrd."""
    out: dict[str, set[str]] = {}
    for chunk in RrdReader(path).stream():
        out.setdefault(chunk.entity_path, set()).update(chunk.to_record_batch().schema.names)
    return out
