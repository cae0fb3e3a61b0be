"""A part of a long run for `capm-field review --targets A-B`.

Rerun's file index fails somewhere past ~50 000 chunks (`TooManyTables`: nothing written), and a
target makes ~23 of them (docs/log.md), so a run of thousands of targets is reviewed a part at a
time. A part is a log-time window: from its first target's first message (`/plan`, `/regions`,
`/key_state` or `/detection` carrying its id) to the next target's; the first part also holds what
came before the first target, the last what came after. A topic with no message inside the window
(`/robot_description`, `/robot/meshes`: written once at the start) keeps its latest one before it,
so every part draws the robot. What review draws itself from a message naming a target (plan,
regions, key states, detection, energy, bench truth) goes with that target, not with the window.
"""

from __future__ import annotations

import re
from array import array
from collections import defaultdict
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

from capm_field.errors import UserError

from .runlog import TOPICS

if TYPE_CHECKING:
    from .review import RunData

# targets reviewed at once by default: ~23 Rerun chunks a target (a 1 000-target bench log made
# 23 600) against the ~50 000 Rerun's index holds, with room for targets that looked twice
PART_TARGETS = 1500
# the topics whose messages say which target the run is at, in the order it began them
_TARGET_TOPICS = tuple(TOPICS[k] for k in ("plan", "regions", "key_state", "detection"))
_TARGETS_RE = re.compile(r"\s*(\d{1,9})\s*(?:-\s*(\d{1,9})\s*)?")


@dataclass
class Part:
    first: int  # 0-based positions in `order`, inclusive
    last: int
    order: list[str]  # every target id of the run, in the order the run began them
    t0: int | None  # log-time window [t0, t1); None: open on that side
    t1: int | None
    keep: set[int] = field(default_factory=set)  # message records handed to Rerun's importer

    @property
    def ids(self) -> list[str]:
        return self.order[self.first : self.last + 1]

    def describe(self) -> str:
        return f"targets {self.first}–{self.last} of {len(self.order)} ({self.ids[0]} … {self.ids[-1]})"


def parse_targets(text: str) -> tuple[int, int]:
    """`A-B` (or `A`): 0-based target positions, inclusive."""
    m = _TARGETS_RE.fullmatch(text)
    if not m:
        raise UserError(f"--targets {text[:80]!r}: give A-B or A (0-based positions in the order the run began its targets)")
    a = int(m.group(1))
    b = int(m.group(2)) if m.group(2) is not None else a
    if b < a:
        raise UserError(f"--targets {text}: the first position is after the last")
    return a, b


def target_order(data: "RunData") -> tuple[list[str], dict[str, int]]:
    """Target ids in the order the run began them, and each one's first log time."""
    start: dict[str, int] = {}
    for topic in _TARGET_TOPICS:
        for t, m in data.messages.get(topic, ()):
            tid = m.target_id
            if tid not in start or t < start[tid]:
                start[tid] = t
    order = sorted(start, key=lambda k: (start[k], k))
    return order, start


def select(data: "RunData", first: int, last: int) -> tuple["RunData", Part]:
    """The part of `data` holding targets first..last (clipped to the run's), and its message records."""
    order, start = target_order(data)
    if not order:
        raise UserError("--targets: this run log holds no target (no /plan, /regions, /key_state or /detection)")
    if first >= len(order):
        raise UserError(f"--targets {first}-{last}: the run holds {len(order)} targets (positions 0–{len(order) - 1})")
    last = min(last, len(order) - 1)
    t0 = start[order[first]] if first > 0 else None
    t1 = start[order[last + 1]] if last + 1 < len(order) else None
    part = Part(first, last, order, t0, t1)

    def inside(t: int) -> bool:
        return (t0 is None or t >= t0) and (t1 is None or t < t1)

    for times, records in data.index.values():
        n_in = 0
        latest, latest_t = -1, None
        for t, r in zip(times, records):
            if inside(t):
                part.keep.add(r)
                n_in += 1
            elif t0 is not None and t < t0 and (latest_t is None or t >= latest_t):
                latest, latest_t = r, t
        if n_in == 0 and latest >= 0:  # written once before the window (the robot's description)
            part.keep.add(latest)

    # what review draws itself: a message naming a target goes with its target (the bench truth is
    # logged at the run's start, a target's last key state may share the next one's first time), the
    # others (igniter state) with the window
    ids = set(part.ids)
    messages: dict[str, list] = defaultdict(list)
    for topic, ms in data.messages.items():
        for t, m in ms:
            tid = getattr(m, "target_id", None)
            if tid in ids or (tid is None and inside(t)):
                messages[topic].append((t if t0 is None else max(t, t0), m))
    on_path = [k for k, t in enumerate(data.body_times) if inside(t)]
    times = [t for topic, (ts, _) in data.index.items() for t in ts if inside(t)]
    sub = replace(
        data,
        messages=messages,
        body_path=[data.body_path[k] for k in on_path],
        body_times=array("q", (data.body_times[k] for k in on_path)),
        first_ns=min(times, default=data.first_ns),
        last_ns=max(times, default=data.last_ns),
        part=part,
    )
    return sub, part

