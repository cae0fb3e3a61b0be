"""Protobuf schemas of the run log's custom messages, built at runtime from descriptors.

Why descriptors in Python instead of a `.proto` file: compiling a `.proto` at runtime needs
protoc or grpcio-tools (not dependencies), and checked-in generated `_pb2.py` code drifts from
its source. Building the `FileDescriptorProto` here gives one source of truth that both
serialises the messages and is embedded, as a `FileDescriptorSet`, in the MCAP schema records,
so Foxglove, Rerun and `mcap-protobuf-support` decode the log without any project code.

All messages live in one file `capm_field/runlog.proto`, package `capm.log`; times are
`google.protobuf.Timestamp` (named `timestamp`, like the Foxglove schemas). Optional values
are sub-messages (proto3 gives message fields presence): an unset `pixel` means "no detection".
"""

from __future__ import annotations

from functools import cache
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory, timestamp_pb2

PACKAGE = "capm.log"
FILE_NAME = "capm_field/runlog.proto"

_T = descriptor_pb2.FieldDescriptorProto
_SCALARS = {
    "double": _T.TYPE_DOUBLE,
    "bool": _T.TYPE_BOOL,
    "string": _T.TYPE_STRING,
    "uint32": _T.TYPE_UINT32,
}

# message name -> [(field name, type, repeated)]; a type not in _SCALARS is a message name.
MESSAGES: dict[str, list[tuple[str, str, bool]]] = {
    "Point2": [("x", "double", False), ("y", "double", False)],
    "Pose2": [("x", "double", False), ("y", "double", False), ("yaw", "double", False)],
    "Troi": [("id", "string", False), ("x", "double", False), ("y", "double", False), ("r", "double", False)],
    "Annulus": [("r_inner", "double", False), ("r_outer", "double", False)],
    "Term": [("name", "string", False), ("value", "double", False)],
    "KeyState": [
        ("timestamp", ".google.protobuf.Timestamp", False),
        ("target_id", "string", False),
        ("planner", "string", False),
        ("label", "string", False),  # x_k0 | x_b,k1 | x_e,k2 | x_b,k3 | x_e,k3 | x_kmax
        ("body", "Pose2", False),  # field frame
        ("arm", "string", False),  # "" (body state) | observe | flame
        ("target", "Point2", False),  # field frame; unset when the key state has none
        ("radius", "double", False),  # r_w for observe, 0 otherwise
        ("note", "string", False),
        ("frame_id", "string", False),
    ],
    "Plan": [
        ("timestamp", ".google.protobuf.Timestamp", False),
        ("target_id", "string", False),
        ("planner", "string", False),
        ("troi", "Troi", False),
        ("start", "Pose2", False),
        ("end", "Pose2", False),
        ("key_states", "KeyState", True),
        ("p_upper", "double", False),  # p(x_b,k1)
        ("expected_cost", "double", False),  # c0 + p·cu + (1-p)·cl
        ("fallback_k3", "Pose2", False),
        ("terms", "Term", True),
        ("frame_id", "string", False),
    ],
    "Detection": [
        ("timestamp", ".google.protobuf.Timestamp", False),
        ("target_id", "string", False),
        ("found", "bool", False),
        ("pixel", "Point2", False),  # (u, v) in /camera/image; unset when not found
        ("confidence", "double", False),
        ("reason", "string", False),  # why not found / rejected; "" otherwise
        ("mpoi_field", "Point2", False),  # MPOI on the ground, field frame
        ("frame_id", "string", False),
        # (u, v) px in /camera/image: the rim of the ROI searched (the TROI disc × the ROI margin,
        # through the lens); empty when no ROI. Added after the first logs: may be absent there.
        ("roi_rim", "Point2", True),
    ],
    "Regions": [
        ("timestamp", ".google.protobuf.Timestamp", False),
        ("target_id", "string", False),
        ("troi", "Troi", False),
        ("ro", "Annulus", True),  # R_o: annuli around X_w
        ("mpoi", "Point2", False),
        ("rm", "Annulus", True),  # R_m: annuli around the MPOI (around X_w while `mpoi` is unset)
        ("frame_id", "string", False),
    ],
    "Energy": [
        ("timestamp", ".google.protobuf.Timestamp", False),
        ("total", "double", False),
        ("target_id", "string", False),
        ("target_energy", "double", False),
        ("body_moves", "uint32", False),
    ],
    "IgniterStatus": [
        ("timestamp", ".google.protobuf.Timestamp", False),
        ("flame_on", "bool", False),
        ("armed", "bool", False),
        ("fuel", "double", False),  # remaining, 0..1
        ("fault", "string", False),
        ("interlock_ok", "bool", False),
        ("interlock_reasons", "string", True),
        ("body_stationary", "bool", False),
        ("epmc_ok", "bool", False),
        ("estop", "bool", False),
    ],
    "TruthMpoi": [
        ("timestamp", ".google.protobuf.Timestamp", False),
        ("target_id", "string", False),
        ("mpoi", "Point2", False),
        ("frame_id", "string", False),
    ],
}

# Fields added after the first run logs: a log written before them is still ours without them.
ADDED_FIELDS: dict[str, frozenset[str]] = {"Detection": frozenset({"roi_rim"})}

# Messages that are published on a topic (the rest are building blocks).
TOP_LEVEL = ("KeyState", "Plan", "Detection", "Regions", "Energy", "IgniterStatus", "TruthMpoi")


def file_descriptor() -> descriptor_pb2.FileDescriptorProto:
    fd = descriptor_pb2.FileDescriptorProto(name=FILE_NAME, package=PACKAGE, syntax="proto3")
    fd.dependency.append(timestamp_pb2.DESCRIPTOR.name)
    for name, fields in MESSAGES.items():
        m = fd.message_type.add(name=name)
        for number, (fname, ftype, repeated) in enumerate(fields, start=1):
            f = m.field.add(name=fname, number=number, json_name=_camel(fname))
            f.label = _T.LABEL_REPEATED if repeated else _T.LABEL_OPTIONAL
            if ftype in _SCALARS:
                f.type = _SCALARS[ftype]
            else:
                f.type = _T.TYPE_MESSAGE
                f.type_name = ftype if ftype.startswith(".") else f".{PACKAGE}.{ftype}"
    return fd


def _camel(s: str) -> str:
    head, *rest = s.split("_")
    return head + "".join(w.title() for w in rest)


@cache
def descriptor_set_bytes() -> bytes:
    """FileDescriptorSet (ours + timestamp.proto) — the `data` of every custom schema record."""
    ts = descriptor_pb2.FileDescriptorProto()
    timestamp_pb2.DESCRIPTOR.CopyToProto(ts)
    return descriptor_pb2.FileDescriptorSet(file=[ts, file_descriptor()]).SerializeToString()


@cache
def _pool() -> descriptor_pool.DescriptorPool:
    # A private pool: no clash with anything registered in the default pool.
    pool = descriptor_pool.DescriptorPool()
    for fd in descriptor_pb2.FileDescriptorSet.FromString(descriptor_set_bytes()).file:
        pool.Add(fd)
    return pool


@cache
def message_class(name: str) -> type:
    """Python class of message `name` (e.g. "IgniterStatus")."""
    return message_factory.GetMessageClass(_pool().FindMessageTypeByName(f"{PACKAGE}.{name}"))


def full_name(name: str) -> str:
    return f"{PACKAGE}.{name}"


def descriptor_problem(theirs: Any, ours: Any, seen: set[str] | None = None) -> str | None:
    """Why a message decoded with the file's descriptor `theirs` cannot be read as our `ours`
    (a field is missing, or of another type or cardinality), else None. A hand-made or foreign
    file may name our schema with other fields: reading them would crash. All our fields are
    required but those added since the first run logs (`ADDED_FIELDS`), which an older log lacks."""
    seen = set() if seen is None else seen
    if ours.full_name in seen:
        return None
    seen.add(ours.full_name)
    added = ADDED_FIELDS.get(ours.name, frozenset())
    for f in ours.fields:
        g = theirs.fields_by_name.get(f.name)
        if g is None and f.name in added:
            continue
        if g is None:
            return f"its {theirs.full_name} has no field {f.name}"
        if g.type != f.type or g.is_repeated != f.is_repeated:
            return f"its {theirs.full_name}.{f.name} is of another type than ours"
        if f.message_type is not None:
            why = descriptor_problem(g.message_type, f.message_type, seen)
            if why:
                return why
    return None


def foreign_problem(schema: str, data: Any, want: str, checked: dict[Any, str | None]) -> str | None:
    """Why a message read from a log under `schema` (decoded to `data`) is not the `want` message
    a reader of a topic expects, else None: a foreign or hand-made file may carry anything on our
    topics. Our messages are checked field by field (`checked`: descriptor -> problem, a cache);
    Foxglove's by name only, so their readers still catch what their fields lack."""
    if schema != want:
        return f"schema {schema or '(none)'!r}, expected {want}"
    if isinstance(data, (bytes, str)):  # an encoding with no decoder here (json, ...)
        return f"{want} in an encoding other than protobuf"
    if want.startswith(PACKAGE + "."):
        desc = data.DESCRIPTOR
        if desc not in checked:
            checked[desc] = descriptor_problem(desc, message_class(want.removeprefix(PACKAGE + ".")).DESCRIPTOR)
        if checked[desc]:
            return f"{want} with another descriptor: {checked[desc]}"
    return None
