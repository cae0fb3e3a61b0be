"""Zenoh body protocol, shared by the client (`ZenohBody`) and the robot side (`BodyServer`).

Key expressions, the CBOR codec with validation, and the zenoh session config. The spec for
foreign clients is docs/protocols/body-zenoh.md; keep the two in step (VERSION bumps on any
incompatible change).
"""

from __future__ import annotations

import io
import json
import os
import re
import ssl
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import cbor2

from capm_field.errors import finite_real, shown
from capm_field.geometry import FIELD_EXTENT_M

VERSION = 1
MAX_PAYLOAD = 4096  # bytes; anything larger is malformed (bounds decoding work on hostile input)
GOAL_EXTENT_M = FIELD_EXTENT_M  # |x|, |y| of a Move goal (field-frame metres, as mission files): beyond it, a unit error

_ID_RE = re.compile(r"[A-Za-z0-9_-]{1,64}")  # whole string (fullmatch: `$` would also take a final newline)
TEXT_MAX = 256  # characters of a text field; longer is malformed (bounds what a peer can make us log or echo)

# Query keys (relative to the body prefix) and the request kind each one carries.
QUERIES = {
    "cmd/move": "move",
    "cmd/stop": "stop",
    "cmd/power": "power",
    "lease/acquire": "lease_acquire",
    "lease/release": "lease_release",
    "estop/checkin": "checkin",
}
MOVE_STATUSES = ("running", "succeeded", "failed", "stopped", "estop", "timeout")


class ProtocolError(ValueError):
    """A payload or key that the protocol does not allow. `tag` is what the counters count."""

    def __init__(self, tag: str, detail: str) -> None:
        super().__init__(f"{tag}: {detail}")
        self.tag, self.detail = tag, detail


def check_id(kind: str, value: str) -> str:
    if not isinstance(value, str) or not _ID_RE.fullmatch(value):
        raise ValueError(f"{kind} must match [A-Za-z0-9_-]{{1,64}}, got {shown(value)}")
    return value


class Keys:
    """All key expressions of one robot's body: `capm/<robot_id>/body/...`."""

    def __init__(self, robot_id: str) -> None:
        self.robot_id = check_id("robot_id", robot_id)
        self.prefix = p = f"capm/{robot_id}/body"
        self.cmd_move, self.cmd_stop, self.cmd_power = f"{p}/cmd/move", f"{p}/cmd/stop", f"{p}/cmd/power"
        self.lease_acquire, self.lease_release = f"{p}/lease/acquire", f"{p}/lease/release"
        self.estop_checkin = f"{p}/estop/checkin"
        self.state, self.feedback, self.alive = f"{p}/state", f"{p}/feedback", f"{p}/alive"
        self.all, self.clients = f"{p}/**", f"{p}/client/*"

    def client(self, client_id: str) -> str:
        return f"{self.prefix}/client/{check_id('client_id', client_id)}"

    def relative(self, key: str) -> str | None:
        """`key` relative to the prefix, or None if it is not under it."""
        p = self.prefix + "/"
        return key[len(p):] if key.startswith(p) else None


# ---- codec -------------------------------------------------------------------------------------
# Field specs: name -> (type, required). Types: str, int, float, bool, id, pose, map, str?, ...
_POSE = {"x": ("float", True), "y": ("float", True), "yaw": ("float", True)}
_GOAL = {"x": ("coord", True), "y": ("coord", True), "yaw": ("float", True)}
_CMD = {"id": ("int", True), "status": ("status", True), "reason": ("str?", False)}
SCHEMAS: dict[str, dict[str, tuple[str, bool]]] = {
    # requests
    "move": {"client": ("id", True), "lease": ("str", True), "goal": ("goal", True), "timeout_ns": ("int", True)},
    "stop": {"client": ("id", True)},
    "power": {"client": ("id", True), "lease": ("str", True), "on": ("bool", True)},
    "lease_acquire": {"client": ("id", True), "lease": ("str?", False)},
    "lease_release": {"client": ("id", True), "lease": ("str", True)},
    "checkin": {"client": ("id", True), "seq": ("int", True), "engage": ("bool?", False), "lease": ("str?", False)},
    # replies
    "ack": {"ok": ("bool", True), "cmd_id": ("int", False), "lease": ("str", False), "ttl_ns": ("int", False),
            "timeout_ns": ("int", False), "estop": ("bool", False)},
    "error": {"ok": ("bool", True), "error": ("str", True), "detail": ("str", True)},
    # publications
    "state": {"t_ns": ("int", True), "seq": ("int", True), "pose": ("pose", True), "moving": ("bool", True),
              "powered": ("bool", True), "estop": ("bool", True), "estop_reason": ("str?", False),
              "odometry_m": ("float", True), "moves": ("int", True), "fault": ("str?", False),
              "cmd": ("cmd?", False), "lease_holder": ("str?", False)},
    "feedback": {"t_ns": ("int", True), "cmd_id": ("int", True), "status": ("status", True),
                 "reason": ("str?", False), "pose": ("pose", True)},
}


def one_line(detail: str, limit: int = TEXT_MAX) -> str:
    """An Error map's `detail`: one line of at most `limit` characters, whatever text (a peer's
    key, ids) went into it."""
    text = " ".join(str(detail).split())
    return text if len(text) <= limit else text[:limit - 1] + "…"


def _check(value: Any, typ: str, name: str) -> None:
    if typ.endswith("?"):
        if value is None:
            return
        typ = typ[:-1]
    ok = {
        "str": lambda v: isinstance(v, str) and len(v) <= TEXT_MAX,
        "id": lambda v: isinstance(v, str) and bool(_ID_RE.fullmatch(v)),
        "int": lambda v: isinstance(v, int) and not isinstance(v, bool) and -(2**63) <= v < 2**64,
        "float": finite_real,  # (an int a float can hold is a real; a CBOR bignum is not)
        "coord": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and abs(v) <= GOAL_EXTENT_M,
        "bool": lambda v: isinstance(v, bool),
        "status": lambda v: v in MOVE_STATUSES,
        "pose": lambda v: isinstance(v, dict),
        "goal": lambda v: isinstance(v, dict),
        "cmd": lambda v: isinstance(v, dict),
    }[typ](value)
    if not ok:
        need = f"a number within ±{GOAL_EXTENT_M:.0f} m" if typ == "coord" else typ
        raise ProtocolError("malformed", f"field {name!r} must be {need}, got {shown(value)}")
    if typ in ("pose", "goal"):
        _check_map(value, _POSE if typ == "pose" else _GOAL, name + ".")
    elif typ == "cmd":
        _check_map(value, _CMD, name + ".")


def _check_map(msg: dict, spec: dict[str, tuple[str, bool]], where: str = "") -> None:
    for name, (typ, required) in spec.items():
        if name not in msg:
            if required:
                raise ProtocolError("malformed", f"missing field {where + name!r}")
            continue
        _check(msg[name], typ, where + name)


def encode(kind: str, msg: Mapping[str, Any]) -> bytes:
    """CBOR map with the version field first. Validates outgoing messages too (catches our bugs)."""
    out = {"v": VERSION, **msg}
    _check_map(out, SCHEMAS[kind])
    return cbor2.dumps(out)


class _RefusedTag(Exception):
    pass


def _refuse(tag: int, what: str):
    def refuse(*_decoder_and_tag) -> None:  # (cbor2 passes the decoder, and the tag since 6)
        raise _RefusedTag(f"CBOR tag {tag} ({what}) is not accepted")

    return refuse


# Shared references (tags 28/29) let a few hundred bytes stand for a structure of 2^depth parts
# (each level two references to the one below), or a cycle: anything that then walks or prints the
# message (a repr in an error line) would take the process, its state loop and its E-stop
# keep-alive with it. No message of this protocol needs them (docs/protocols/body-zenoh.md).
_REFUSED_TAGS = {28: _refuse(28, "shareable"), 29: _refuse(29, "shared reference")}


def _decode_failure(e: Exception) -> str:
    """What a decoder failure says about the payload. (A function, not locals of `decode`: an
    exception kept in a local would tie `decode`'s frame, and through it the caller's zenoh query,
    into a reference cycle, and the query would stay open until the garbage collector ran.)"""
    if "duplicate map key" in str(e).lower():
        return "a map with a key twice"
    refused = e.__cause__ or e.__context__  # (cbor2 wraps a semantic decoder's exception)
    return str(refused) if isinstance(refused, _RefusedTag) else f"not CBOR ({type(e).__name__})"


def decode(kind: str, raw: bytes | None) -> dict[str, Any]:
    """Decode and validate one message of `kind`; raises ProtocolError('malformed'|'bad_version')."""
    if raw is None or len(raw) == 0:
        raise ProtocolError("malformed", "empty payload")
    if len(raw) > MAX_PAYLOAD:
        raise ProtocolError("malformed", f"payload of {len(raw)} bytes exceeds {MAX_PAYLOAD}")
    try:
        buf = io.BytesIO(raw)
        # a map with a key twice is not valid CBOR (RFC 8949 §5.6): one decoder would keep the
        # first, another the last (an engage read as a release), so it is malformed here
        msg = cbor2.CBORDecoder(buf, allow_duplicate_keys=False, semantic_decoders=_REFUSED_TAGS).decode()
    except Exception as e:  # noqa: BLE001 - any decoder failure is a malformed payload
        raise ProtocolError("malformed", _decode_failure(e)) from None
    if buf.tell() != len(raw):  # one map per message: bytes after it are a framing error (two messages, junk)
        raise ProtocolError("malformed", f"{len(raw) - buf.tell()} bytes after the CBOR map")
    if not isinstance(msg, dict):
        raise ProtocolError("malformed", "top level must be a CBOR map")
    v = msg.get("v")
    if not isinstance(v, int) or isinstance(v, bool):
        raise ProtocolError("malformed", "missing integer field 'v' (protocol version)")
    if v != VERSION:
        raise ProtocolError("bad_version", f"protocol version {shown(v)} not supported (this side speaks {VERSION})")
    _check_map(msg, SCHEMAS[kind])
    return msg


def pose_map(x: float, y: float, yaw: float) -> dict[str, float]:
    return {"x": float(x), "y": float(y), "yaw": float(yaw)}


# ---- zenoh session config ----------------------------------------------------------------------
@dataclass(frozen=True)
class LinkConfig:
    """Where and how a zenoh session connects. Explicit endpoints only: multicast and gossip
    scouting are off unless asked for, and nothing listens unless `listen` says so (the zenoh
    default peer listens on every interface).

    `config_file` (a zenoh JSON5/YAML file: TLS, user/password, access control; see
    mission/examples/zenoh-*.json5 and docs/security.md) or `base_json5` (the same as text) is
    the config to start from; relative certificate/key/dictionary paths in a file are taken
    relative to the file. The fields here are applied on top of it (endpoints, mode, scouting
    and lease always come from here), then `overrides` (zenoh config path -> value, e.g.
    {"transport/link/tls/root_ca_certificate": "/etc/ca.pem"}) last.
    """

    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    mode: str = "peer"
    lease_ms: int = 1000  # transport.link.tx.lease: a frozen peer is declared dead after this
    keep_alive: int = 4  # keep-alive messages per lease period
    multicast: bool = False
    gossip: bool = False
    base_json5: str | None = None
    config_file: str | None = None
    overrides: Mapping[str, Any] = field(default_factory=dict)

    def zenoh_config(self):  # -> zenoh.Config (imported lazily: the codec needs no zenoh)
        import zenoh

        if self.config_file and self.base_json5:
            raise ValueError("give config_file or base_json5, not both")
        if self.config_file:
            cfg = load_config_file(self.config_file)
        else:
            cfg = zenoh.Config.from_json5(self.base_json5) if self.base_json5 else zenoh.Config()
        items: dict[str, Any] = {
            "mode": self.mode,
            "connect/endpoints": list(self.connect),
            "listen/endpoints": list(self.listen),
            "scouting/multicast/enabled": self.multicast,
            "scouting/gossip/enabled": self.gossip,
            "transport/link/tx/lease": int(self.lease_ms),
            "transport/link/tx/keep_alive": int(self.keep_alive),
        }
        items.update(self.overrides)
        for path, value in items.items():
            cfg.insert_json5(path, json.dumps(value))
        return cfg


# Config paths that name files: made absolute against the config file's directory.
FILE_KEYS = (
    "transport/link/tls/root_ca_certificate",
    "transport/link/tls/listen_private_key",
    "transport/link/tls/listen_certificate",
    "transport/link/tls/connect_private_key",
    "transport/link/tls/connect_certificate",
    "transport/auth/usrpwd/dictionary_file",
)


def load_config_file(path: str | os.PathLike):  # -> zenoh.Config
    """Load a zenoh config file (JSON5 or YAML), with relative file paths (certificates, keys,
    the user/password dictionary) resolved against the file's directory rather than the
    process's working directory. A missing file named by one of them is an error here, at
    start, not a TLS handshake that fails later on every connection."""
    import zenoh

    p = Path(path).expanduser()
    if not p.is_file():
        raise FileNotFoundError(f"zenoh config file not found: {p}")
    _check_config_text(p)
    cfg = zenoh.Config.from_file(str(p))
    for key in FILE_KEYS:
        value = json.loads(cfg.get_json(key))
        if not isinstance(value, str) or not value:
            continue
        f = Path(value).expanduser()
        if not f.is_absolute():
            f = (p.parent / f).resolve()
            cfg.insert_json5(key, json.dumps(str(f)))
        if not f.is_file():
            if f.exists():  # a directory, a device, a FIFO (whose read would block)
                raise ValueError(f"{p}: {key.replace('/', '.')} names {f}, which is not a regular file")
            raise FileNotFoundError(f"{p}: {key.replace('/', '.')} names a missing file: {f}")
        _check_pem(p, key, f)
    for side in ("listen", "connect"):  # a key that does not match its certificate fails every handshake
        cert, key = (json.loads(cfg.get_json(f"transport/link/tls/{side}_{k}")) for k in ("certificate", "private_key"))
        if isinstance(cert, str) and cert and isinstance(key, str) and key:
            try:
                ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER).load_cert_chain(cert, key)
            except (ssl.SSLError, OSError) as e:
                raise ValueError(f"{p}: transport.link.tls.{side}_private_key {key} does not go with "
                                 f"{side}_certificate {cert} ({e.__class__.__name__}: {e})") from None
    return cfg


MAX_CONFIG_BYTES = 1 << 20
MAX_CONFIG_DEPTH = 64  # a zenoh config nests < 10 deep; zenoh's JSON5 parser recurses (~20 000 levels crash it)


_RUST_SOURCE = re.compile(r"\s*at /\S+\.rs:\d+\.?")
_SERDE_MESSAGE = re.compile(r'Message \{ msg: "(?P<msg>.*?)", location: (?:Some\(Location \{ line: (?P<line>\d+), column: (?P<col>\d+) \}\)|None) \}')
_PEST_ERROR = re.compile(r"^\s*-->\s*(?P<line>\d+):(?P<col>\d+).*?=\s*(?P<msg>[^\n]+?)\s*$", re.S)


def zenoh_error_text(e: BaseException) -> str:
    """zenoh's error as one line for a field engineer: without its Rust source path, and with
    serde's / the JSON5 parser's debug structs read out (`line L, column C: what`)."""
    text = _RUST_SOURCE.sub("", str(e))
    m = _PEST_ERROR.match(text)
    if m:
        return f"line {m['line']}, column {m['col']}: {' '.join(m['msg'].split())}"
    text = " ".join(text.split())
    wrapped = re.fullmatch(r"\w+Err\((.*)\)", text)  # e.g. Json5Err(...): an enum variant's debug form
    text = wrapped[1] if wrapped else text
    m = _SERDE_MESSAGE.search(text)
    if m:
        where = f"line {m['line']}, column {m['col']}: " if m["line"] else ""
        text = text[: m.start()] + where + m["msg"].replace('\\"', '"') + text[m.end():]
    return text or type(e).__name__


def _check_config_text(p: Path) -> None:
    """Refuse what zenoh's own parser does not survive: it runs in this process and overflows its
    stack (SIGSEGV, no exception) on brackets nested ~20 000 deep. Size first, then depth."""
    size = p.stat().st_size
    if size > MAX_CONFIG_BYTES:
        raise ValueError(f"{p}: {size} bytes is too large for a zenoh config file (limit {MAX_CONFIG_BYTES})")
    depth = _max_nesting(p.read_bytes())
    if depth > MAX_CONFIG_DEPTH:
        raise ValueError(f"{p}: brackets nested {depth} deep: not a zenoh config file (limit {MAX_CONFIG_DEPTH})")


def _max_nesting(text: bytes) -> int:
    """Deepest nesting of {} and [] outside JSON5 strings and comments (YAML flow style alike)."""
    depth = deepest = i = 0
    n = len(text)
    while i < n:
        c = text[i]
        if c in b"\"'":  # a string: skip to its closing quote (backslash escapes)
            i += 1
            while i < n and text[i] != c:
                i += 2 if text[i] == 0x5C else 1
        elif text.startswith(b"//", i) or c == 0x23:  # // or # comment: to the end of the line
            while i < n and text[i] != 0x0A:
                i += 1
        elif text.startswith(b"/*", i):
            end = text.find(b"*/", i + 2)
            i = n if end < 0 else end + 1
        elif c in b"{[":
            depth += 1
            deepest = max(deepest, depth)
        elif c in b"}]":
            depth -= 1
        i += 1
    return deepest


MAX_PEM_BYTES = 4 << 20  # a CA bundle (Mozilla's: ~220 kB) fits many times over


def _check_pem(cfg_path: Path, key: str, f: Path) -> None:
    """A certificate or key file named by the config must be PEM of that kind (a text file with
    anything else in it only fails at the first TLS handshake, on the robot)."""
    if not key.startswith("transport/link/tls/"):
        return
    what = key.rsplit("/", 1)[-1].replace("_", " ")
    size = f.stat().st_size
    if size > MAX_PEM_BYTES:
        raise ValueError(f"{cfg_path}: {key.replace('/', '.')}: {f} is {size} bytes, too large for a PEM file "
                         f"(limit {MAX_PEM_BYTES})")
    text = f.read_bytes()
    if key.endswith("certificate"):
        # the first block, found in linear time (a lazy regex retried from each of 20 000 BEGIN
        # lines took minutes: a hostile file must not hang `validate` or the bridge's start)
        begin = text.find(b"-----BEGIN CERTIFICATE-----")
        end = text.find(b"-----END CERTIFICATE-----", begin + 28) if begin >= 0 else -1
        block = text[begin:end + 25] if end >= 0 else None
        try:
            ssl.PEM_cert_to_DER_cert(block.decode("ascii")) if block else None
        except (ValueError, UnicodeDecodeError):
            block = None
        if not block:
            raise ValueError(f"{cfg_path}: {key.replace('/', '.')}: {f} is not a PEM certificate ({what})")
        try:  # PEM armour around something that is not a certificate fails every handshake
            ssl.create_default_context(cadata=block.decode("ascii"))
        except (ssl.SSLError, ValueError) as e:
            raise ValueError(f"{cfg_path}: {key.replace('/', '.')}: {f} holds no valid certificate ({what}: {e})") from None
    elif not re.search(rb"-----BEGIN [A-Z ]*PRIVATE KEY-----", text):
        raise ValueError(f"{cfg_path}: {key.replace('/', '.')}: {f} is not a PEM private key ({what})")


def link_security(cfg) -> dict[str, Any]:
    """What a zenoh config enforces, read back from the config itself (for logs and checks):
    `tls` (some endpoint is tls/ or quic/), `mtls`, `usrpwd` (a dictionary of users is set: peers
    must authenticate), `acl` (access control on with default deny), `endpoints` (listen +
    connect), `loopback_only` (every endpoint, listen and connect, is on 127.0.0.0/8, ::1 or
    localhost, and multicast scouting is off: nothing off this machine can reach the session)."""

    def get(key: str) -> Any:
        return json.loads(cfg.get_json(key))

    def endpoints(key: str) -> list[str]:
        v = get(key) or []
        if isinstance(v, dict):  # per-mode form {router: [...], peer: [...], client: [...]}
            return [str(e) for lst in v.values() for e in (lst or [])]
        return [str(e) for e in v]

    listen, connect = endpoints("listen/endpoints"), endpoints("connect/endpoints")
    ends = listen + connect
    acl = get("access_control") or {}
    return {
        "tls": bool(ends) and all(e.split("/", 1)[0] in ("tls", "quic") for e in ends),
        "mtls": bool(get("transport/link/tls/enable_mtls")),
        "usrpwd": bool(get("transport/auth/usrpwd/dictionary_file")),
        "acl": bool(acl.get("enabled")) and acl.get("default_permission") == "deny",
        "endpoints": ends,
        "loopback_only": all(is_loopback_endpoint(e) for e in ends) and not get("scouting/multicast/enabled"),
    }


def is_loopback_endpoint(endpoint: str) -> bool:
    """True for `proto/127.x.y.z:port`, `proto/[::1]:port`, `proto/localhost:port` (zenoh locators;
    anything after `#` or `?` is ignored)."""
    import ipaddress

    addr = endpoint.split("/", 1)[-1].split("#", 1)[0].split("?", 1)[0]
    host = addr.rsplit(":", 1)[0].strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def close_at_interpreter_exit(obj: Any) -> None:
    """Close `obj` when the interpreter exits, before it waits for non-daemon threads.

    A zenoh subscriber with a Python callback runs on a non-daemon thread that lives as long as
    the session; a program that forgets `close()` would hang at exit. `threading._register_atexit`
    (what concurrent.futures uses) runs before that join; plain `atexit` runs after it. Weakly
    held, so it never keeps a driver alive.
    """
    import threading
    import weakref

    ref = weakref.ref(obj)

    def _close() -> None:
        o = ref()
        if o is not None:
            try:
                o.close()
            except Exception:  # noqa: BLE001 - exit must go on
                pass

    register = getattr(threading, "_register_atexit", None)
    if register is not None:
        try:
            register(_close)
        except RuntimeError:  # already shutting down
            pass
