"""Mission file: one YAML document → a validated `Mission` (pydantic), or every problem at once.

Each problem is reported as `FILE:LINE: key.path: message`, using the YAML node marks, and the
loader raises `MissionError` (exit 2, nothing started, nothing written). Unknown keys are errors.
TROIs are listed under `field.trois` or loaded from a prescan file (`field.prescan`: CSV with
columns x,y,r[,id] or GeoJSON Points with a `radius`/`r` property, field-frame metres).
"""

from __future__ import annotations

import collections
import csv
import dataclasses
import io
import json
import math
import os
import re
import unicodedata
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import yaml
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, PrivateAttr, ValidationError, field_validator, model_validator

from capm_field.config import MIN_TROI_RADIUS, RobotConfig, StrictNumbers, TaskConfig, not_bool
from capm_field.errors import UserError, not_a_file, shown
from capm_field.geometry import FIELD_EXTENT_M as FIELD_EXTENT
from capm_field.geometry import SE2
from capm_field.keystates import TROI

PLANNER_NAMES = ("a", "b", "c", "cstar", "field")
MAX_MISSION_BYTES = 2**20  # 5000 listed TROIs take ~0.3 MiB; parsing 1 MiB takes ~1 s of CPU
MAX_PRESCAN_BYTES = 16 * 2**20
MAX_TROIS = 5000  # ~14 h of flaming at ~10 s a weed; ordering them alone takes ~9 s
MAX_TIMEOUT_S = 3600.0
# ids name log lines, summary keys and (escaped) Rerun paths: any printable text of 1–64 characters
# (a prescan tool's "W 12" or "plot A/3" too), not starting or ending with a space
TROI_ID_RE = re.compile(r"^(?=.{1,64}\Z)[^\x00-\x20\x7f-\x9f](?:[^\x00-\x1f\x7f-\x9f]*[^\x00-\x20\x7f-\x9f])?\Z")
NAME_RE = re.compile(r"^(?=.{1,128}\Z)[^\x00-\x20\x7f-\x9f](?:[^\x00-\x1f\x7f-\x9f]*[^\x00-\x20\x7f-\x9f])?\Z")
LEG_MARGIN = 0.8  # a leg of the visit may take at most this share of the body's move timeout


# numbers of `_Strict` models refuse yes/no values through `StrictNumbers`; dict values and the
# fields of `_Tagged` models say so themselves (`not_bool`)
Timeout = Annotated[float, BeforeValidator(not_bool), Field(gt=0.0, le=MAX_TIMEOUT_S)]
Coord = Annotated[float, Field(ge=-FIELD_EXTENT, le=FIELD_EXTENT)]


class MissionError(UserError):
    """A mission file problem; `problems` holds one line per problem."""

    def __init__(self, problems: list[str]):
        self.problems = problems
        super().__init__("\n".join(problems) if len(problems) > 1 else problems[0])


class _Tagged(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class _Strict(StrictNumbers, _Tagged):
    """Strict models whose numbers refuse yes/no values (`_Tagged`: models of a tagged union,
    whose tag field cannot take a before-validator; their numbers say so one by one)."""


class Pose(_Strict):
    x: Coord  # field frame, m
    y: Coord
    yaw: float = Field(0.0, description="rad")

    def se2(self) -> SE2:
        return SE2(self.x, self.y, self.yaw)


def _invisible(v: str) -> bool:
    """Whether `v` holds a character that is no visible text: controls, format characters (U+200B
    zero-width space, U+202E right-to-left override) or line/paragraph separators (U+2028)."""
    return any(unicodedata.category(ch) in ("Cc", "Cf", "Cs", "Zl", "Zp") for ch in v)


def _troi_id(v: str | None) -> str | None:
    if v is not None and v != "" and (not TROI_ID_RE.match(v) or _invisible(v)):  # "" (or none): a generated id
        raise ValueError(f"a TROI id is 1-64 printable characters, no control characters, no space at either end (got {shown(v)})")
    return v or None


class TroiSpec(_Strict):
    id: str | None = None
    x: Coord
    y: Coord
    r: float = Field(ge=MIN_TROI_RADIUS, le=0.5, description="TROI radius r_w (m)")

    @field_validator("id")
    @classmethod
    def _id(cls, v: str | None) -> str | None:
        return _troi_id(v)


class FieldSpec(_Strict):
    trois: list[TroiSpec] = Field(default_factory=list, max_length=MAX_TROIS)
    prescan: str | None = Field(None, description="CSV or GeoJSON file of TROI centres and radii")

    @field_validator("prescan")
    @classmethod
    def _prescan(cls, v: str | None) -> str | None:
        if v is not None and "\0" in v:  # os calls refuse it with a ValueError
            raise ValueError("a file name cannot contain a NUL character")
        return v

    @model_validator(mode="after")
    def _one_source(self) -> "FieldSpec":
        if self.trois and self.prescan:
            raise ValueError("give either trois or prescan, not both")
        return self


class FaultSpec(_Strict):
    """One scheduled fault (bench): `kind` at target index `target` (visit order), in `phase`
    (default: the kind's own), `at_s` seconds into that phase (the same as `params.at_s`)."""

    kind: str
    target: int | None = Field(None, ge=0)
    phase: Literal["walk", "observe", "reposition", "flame", "stow"] | None = None
    at_s: float | None = Field(None, ge=0.0, le=3600.0)
    params: dict[str, Any] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _one_at_s(self) -> "FaultSpec":
        if self.at_s is not None and "at_s" in self.params and self.params["at_s"] != self.at_s:
            raise ValueError(f"at_s given twice ({self.at_s} and params.at_s {self.params['at_s']})")
        return self


class BenchDrivers(_Tagged):
    kind: Literal["bench"]
    seed: Annotated[int, BeforeValidator(not_bool)] = Field(0, ge=0, le=2**63 - 1)  # the range --seed takes
    transport: Literal["inprocess", "wire"] = Field("inprocess", description="in-process sim, or real adapters over loopback")
    faults: list[FaultSpec] | str = Field(default_factory=list, description="list, or 'random:SEED'")
    mpoi_in_troi: bool = Field(True, description="true MPOIs are drawn from N(X_w, Σ_w) restricted to the TROI")


ENDPOINT_RE = re.compile(r"^[a-z][a-z0-9-]*/[^\s#?]+(\?[^\s#]*)?(#\S*)?$")  # zenoh: <protocol>/<address>[?meta][#config]


class ZenohSpec(_Strict):
    robot_id: str = "spot"
    connect: list[str] = Field(default_factory=lambda: ["tcp/192.168.80.3:7447"])
    listen: list[str] = Field(default_factory=list)
    config_file: str | None = Field(None, description="zenoh JSON5 config (mutual TLS, user/password), relative to this "
                                    "file; connect/listen/lease above still apply (docs/security.md)")
    estop_timeout_s: float = Field(1.0, gt=0.0, le=60.0)
    lease_s: float = Field(1.0, gt=0.0, le=60.0)

    @field_validator("robot_id")
    @classmethod
    def _robot_id(cls, v: str) -> str:
        from drivers.body_protocol import check_id  # the protocol's own rule (key expressions)

        return check_id("robot_id", v)

    @field_validator("connect", "listen")
    @classmethod
    def _endpoints(cls, v: list[str]) -> list[str]:
        bad = [e for e in v if not ENDPOINT_RE.match(e)]
        if bad:
            raise ValueError(f"a zenoh endpoint is <protocol>/<address>, e.g. tls/192.168.80.3:7447 (got {shown(bad[0])})")
        return v


class CanSpec(_Strict):
    interface: str = "socketcan"
    channel: str = "can0"
    bitrate: int = Field(1_000_000, gt=0, le=1_000_000, description="classic CAN: ≤ 1 Mbit/s")

    @field_validator("interface")
    @classmethod
    def _interface(cls, v: str) -> str:
        import can

        if v not in can.VALID_INTERFACES:
            raise ValueError(f"unknown python-can interface {shown(v)} (socketcan on the robot)")
        return v


class CameraSpec(_Strict):
    source: str | int = 0
    fourcc: str | None = Field(None, description="pixel format to ask the device for, e.g. YUYV (raw; the detector "
                               "is worse on MJPG frames, docs/perception.md §3); default: the device's own")

    @field_validator("fourcc")
    @classmethod
    def _fourcc(cls, v: str | None) -> str | None:
        if v is not None and not (len(v) == 4 and v.isascii() and v.isprintable()):
            raise ValueError(f"a FOURCC is four printable ASCII characters, e.g. YUYV or MJPG (got {shown(v)})")
        return v


class HardwareDrivers(_Tagged):
    kind: Literal["hardware"]
    zenoh: ZenohSpec = Field(default_factory=ZenohSpec)
    can: CanSpec = Field(default_factory=CanSpec)
    camera: CameraSpec = Field(default_factory=CameraSpec)


FUEL_RESERVE = 0.02  # tank fraction never planned into by default
FUEL_MARGIN = 1.25  # × the expected fuel of one ξ hold (ignition and a relight cost some too)


def hold_fuel(xi_s: float, rate_per_s: float) -> float:
    """Tank fraction one ξ hold is planned to take (0 while no rate is known). The executive
    begins a target only if this much leaves more than the reserve; `validate` uses the same."""
    return FUEL_MARGIN * xi_s * rate_per_s


def holds_left(fuel: float, reserve: float, need: float) -> float:
    """How many holds of `need` can still begin from `fuel`, each leaving more than `reserve`
    (the executive's rule); inf while `need` is unknown (0) or so small that the tank's holds
    overflow a float (a rate of 1e-310/s); 0 for a fuel reading that is not a number."""
    if need <= 0:
        return math.inf
    q = (fuel - reserve) / need
    if math.isnan(q):
        return 0
    if math.isinf(q):
        return math.inf if q > 0 else 0
    return max(0, math.ceil(q) - 1)


class IgniterSpec(_Strict):
    """Fuel budget: a target is begun only if its ξ hold fits above `fuel_reserve`."""

    fuel_per_s: float | None = Field(None, gt=0.0, le=1.0, description="tank fraction burnt per second of flame; "
                                     "unset: measured from the run's own holds (none known before the first)")
    fuel_reserve: float = Field(FUEL_RESERVE, ge=0.0, lt=1.0, description="tank fraction never planned into")


class OutputSpec(_Strict):
    dir: str = "runs/latest"
    images: bool = True
    image_format: Literal["jpeg", "png"] = Field(
        "jpeg", description="jpeg (quality 85: ~155 kB a 1280×720 frame) or png (~1.2 MB; lossless: `capm-field detect-replay` then sees "
        "the very frames the detector saw; on JPEG its answers move with the compression)")

    @field_validator("dir")
    @classmethod
    def _dir(cls, v: str) -> str:
        if not v.strip() or "\0" in v:  # "" would write into the current directory
            raise ValueError("needs a directory name")
        return v


class Mission(_Strict):
    name: str = Field("mission", description="written into summary.json and the run log's metadata")
    robot: RobotConfig = Field(default_factory=RobotConfig)
    task: TaskConfig = Field(default_factory=TaskConfig)
    field: FieldSpec
    start: Pose
    end: Pose | None = Field(None, description="x_kmax after the last TROI; default: the start pose")
    planner: str = "c"
    drivers: BenchDrivers | HardwareDrivers = Field(discriminator="kind")
    igniter: IgniterSpec = Field(default_factory=IgniterSpec)
    output: OutputSpec = Field(default_factory=OutputSpec)
    timeouts: dict[Literal["body", "arm", "camera"], Timeout] = Field(default_factory=lambda: {"body": 60.0, "arm": 20.0, "camera": 5.0},
                                                                   description=f"s, each in (0, {MAX_TIMEOUT_S:.0f}]")

    # where it was read from: error lines about it name the file and the key's line
    _source: Path | None = PrivateAttr(None)
    _lines: dict = PrivateAttr(default_factory=dict)

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        if not NAME_RE.match(v) or _invisible(v):  # it is printed, and written into the summary and the log
            raise ValueError(f"a mission name is 1-128 printable characters, no control characters, no space at either end (got {shown(v)})")
        return v

    @field_validator("planner")
    @classmethod
    def _planner(cls, v: str) -> str:
        if v not in PLANNER_NAMES:
            raise ValueError(f"unknown planner {shown(v)}; choose from {', '.join(PLANNER_NAMES)}")
        return v

    def end_pose(self) -> SE2:
        return (self.end or self.start).se2()

    def where(self, *key: str | int) -> str:
        """`FILE:LINE` of a key path of this mission (the nearest given parent's line)."""
        return f"{self._source or '(mission)'}:{_line_for(self._lines, key) or '?'}"


# ---- reading the YAML -------------------------------------------------------------------------
MAX_NODES = 100_000  # YAML nodes, an alias counted each time it is used (MAX_TROIS listed TROIs: ~5·10⁴)
MAX_INT_DIGITS = 100  # no mission value needs more (int() of over 4300 digits raises a plain ValueError)
_YAML_STR = "tag:yaml.org,2002:str"


class _Expansion(ValueError):
    def __init__(self, node: yaml.Node, problem: str):
        super().__init__(problem)
        self.line = node.start_mark.line + 1


class _ValueInFile(yaml.constructor.ConstructorError):
    """A scalar that YAML 1.1 would read as another value than it shows (`node`: where)."""

    def __init__(self, node: yaml.Node, problem: str):
        super().__init__(None, None, problem, node.start_mark)
        self.node = node


def _number_ambiguity(text: str, leading_zero: bool = True) -> str | None:
    """Why YAML 1.1 (or pydantic after it) reads the plain scalar `text` as a number other than
    it shows, or None: 010 is octal 8, 1_2 is 12, 1:20 is 80 (base 60)."""
    t = text.lstrip("+-")
    if "_" in t:
        why = "YAML 1.1 drops the _"
    elif ":" in t:
        why = "YAML 1.1 reads a:b as base 60"
    elif leading_zero and len(t) > 1 and t[0] == "0" and t[1].isdigit():
        why = "YAML 1.1 reads a leading 0 as octal"
    else:
        return None
    return f"ambiguous number {shown(text)} ({why}): write the number plainly, or quote it if it is text"


class _Loader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):  # libyaml's parser when installed: ~4× faster
    """yaml's safe loader whose numbers read as they show, and whose value errors name the node."""

    def construct_yaml_int(self, node: yaml.ScalarNode) -> int:
        text = str(node.value)
        why = _number_ambiguity(text)
        if why:
            raise _ValueInFile(node, why)
        digits = len(text.lstrip("+-"))
        if digits > MAX_INT_DIGITS:
            raise _ValueInFile(node, f"an integer of {digits} digits is not a mission value (at most {MAX_INT_DIGITS})")
        return super().construct_yaml_int(node)

    def construct_yaml_float(self, node: yaml.ScalarNode) -> float:
        why = _number_ambiguity(str(node.value), leading_zero=False)  # 010.5 is 10.5 to everyone
        if why:
            raise _ValueInFile(node, why)
        return super().construct_yaml_float(node)

    def construct_object(self, node: yaml.Node, deep: bool = False) -> Any:
        try:
            return super().construct_object(node, deep)
        except (ValueError, OverflowError) as e:  # e.g. a timestamp 2024-02-30
            what = f" {shown(node.value)}" if isinstance(node, yaml.ScalarNode) else ""
            raise _ValueInFile(node, f"cannot read the value{what}: {e}") from e


_Loader.add_constructor("tag:yaml.org,2002:int", _Loader.construct_yaml_int)
_Loader.add_constructor("tag:yaml.org,2002:float", _Loader.construct_yaml_float)


def _key_text(key: tuple) -> str:
    return ".".join(str(k) if len(str(k)) <= 40 else f"{str(k)[:40]}…" for k in key)


def _read_yaml(path: Path, text: str) -> tuple[Any, dict[tuple, int], dict[tuple, tuple[bool, str]], list[str]]:
    """Parse once: the data; key path → 1-based line; key path → (quoted?, text) of each text
    scalar; and keys given twice in one mapping (YAML would silently keep the last), as
    `LINE: key: ...` lines. Hostile YAML (nesting, aliases) and values YAML 1.1 would misread
    are MissionErrors."""
    lines: dict[tuple, int] = {}
    texts: dict[tuple, tuple[bool, str]] = {}
    dups: list[str] = []
    paths: dict[int, tuple] = {}

    def walk(node: yaml.Node, path: tuple) -> None:
        lines[path] = node.start_mark.line + 1
        if isinstance(node, yaml.ScalarNode) and node.tag == _YAML_STR:
            texts[path] = (bool(node.style), node.value)  # style: quoted or block; plain is None
        if id(node) in paths:  # an alias: its lines were mapped where it was anchored
            return
        paths[id(node)] = path
        if isinstance(node, yaml.MappingNode):
            seen: dict = {}
            for k, v in node.value:
                # a complex key (`? [a, b]`) is unhashable: name it by its line, pydantic refuses it
                key = k.value if isinstance(k, yaml.ScalarNode) else f"<key on line {k.start_mark.line + 1}>"
                if key in seen:
                    dups.append(f"{k.start_mark.line + 1}: {_key_text(path + (key,))}: key given twice (first on line {seen[key]})")
                seen.setdefault(key, k.start_mark.line + 1)
                lines[path + (key,)] = k.start_mark.line + 1
                walk(v, path + (key,))
        elif isinstance(node, yaml.SequenceNode):
            for i, v in enumerate(node.value):
                walk(v, path + (i,))

    loader = _Loader(text)
    try:
        root = loader.get_single_node()
        if root is None:
            return None, lines, texts, dups
        _check_expansion(root)  # first: walking or constructing an alias bomb would not end
        walk(root, ())
        data = loader.construct_document(root)
    except _Expansion as e:
        raise MissionError([f"{path}:{e.line}: {e}"]) from e
    except RecursionError as e:  # the walks recurse (libyaml itself stops at 1000 levels)
        raise MissionError([f"{path}: the YAML is nested too deeply to be a mission file"]) from e
    except _ValueInFile as e:
        key = paths.get(id(e.node))
        raise MissionError([f"{path}:{e.problem_mark.line + 1}: {_key_text(key) + ': ' if key else ''}{e.problem}"]) from e
    except yaml.YAMLError as e:
        problem = " ".join(str(getattr(e, "problem", None) or e).split())  # a reader error spans lines
        if "maximum nesting depth" in problem:
            raise MissionError([f"{path}: the YAML is nested too deeply to be a mission file"]) from e
        mark = getattr(e, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark else str(path)
        raise MissionError([f"{where}: YAML syntax error: {problem[:300]}"]) from e
    finally:
        loader.dispose()
    return data, lines, texts, dups


def _check_expansion(root: yaml.Node) -> None:
    """Refuse an alias that contains itself, alias "bombs" (a few lines that expand to billions
    of nodes, which validation would then walk) and more nodes than any mission has: count the
    nodes, each alias as often as it is used."""
    size: dict[int, int] = {}
    open_: set[int] = set()
    aliased = False

    def count(node: yaml.Node) -> int:
        nonlocal aliased
        k = id(node)
        if k in size:
            aliased = True  # a node met again: an alias
            return size[k]
        if k in open_:
            raise _Expansion(node, "a YAML alias refers to a node that contains it")
        open_.add(k)
        kids = [x for kv in node.value for x in kv] if isinstance(node, yaml.MappingNode) else \
            node.value if isinstance(node, yaml.SequenceNode) else []
        n = 1
        for c in kids:
            n += count(c)
            if n > MAX_NODES:
                if aliased:
                    raise _Expansion(node, f"YAML aliases expand to more than {MAX_NODES} nodes: not a mission file")
                raise _Expansion(node, f"the YAML has more than {MAX_NODES} nodes: not a mission file ({MAX_TROIS} listed "
                                       f"TROIs take ~{9 * MAX_TROIS}; put long TROI lists in field.prescan)")
        open_.discard(k)
        size[k] = n
        return n

    count(root)


def _line_for(lines: dict[tuple, int], loc: tuple) -> int | None:
    """Line of a key path, or of its nearest parent given in the file."""
    while loc:
        if loc in lines:
            return lines[loc]
        loc = loc[:-1]
    return lines.get(())


# pydantic's names for union members, validators and tagged-union cases, as they appear in an
# error's location (never a mission key)
_TAGS = frozenset({"str", "int", "float", "bool", "list", "dict", "none", "bench", "hardware"})


def _is_tag(el: Any) -> bool:
    return isinstance(el, str) and (el in _TAGS or any(c in el for c in "[](),-") or el[:1].isupper())


def _key_path(data: Any, loc: tuple) -> tuple[tuple, bool]:
    """The file's key path of a pydantic error location (pydantic's own tags left out), and
    whether the error is a union member refusing the value's type (the location ends in a tag)."""
    out: list = []
    cur, at_tag = data, False
    for i, el in enumerate(loc):
        if el == "[key]":  # the key of a dict entry: already named
            continue
        if isinstance(cur, dict) and isinstance(el, (str, int)) and el in cur:
            out.append(el)
            cur, at_tag = cur[el], False
        elif isinstance(cur, list) and isinstance(el, int) and 0 <= el < len(cur):
            out.append(el)
            cur, at_tag = cur[el], False
        elif i == len(loc) - 1 and isinstance(cur, dict) and not _is_tag(el):
            out.append(el)  # a required key that is missing
        else:
            at_tag = True
    return tuple(out), at_tag


def _validation_problems(e: ValidationError, data: Any, lines: dict[tuple, int], path: Path) -> list[str]:
    """One `FILE:LINE: key.path: message (got value)` line per problem. A union's members each
    report; a member that refused the value's type is dropped when another got further (a fault
    list with one bad phase is not also "not a valid string"), and merged when none did."""
    errs = []
    for err in e.errors():
        key, at_tag = _key_path(data, tuple(err["loc"]))
        errs.append((key, at_tag, err["msg"].removeprefix("Value error, "), err["type"], err.get("input")))
    merged: dict[tuple, list] = {}  # key path (of type refusals) → [index into out, messages]
    out: list[list] = []
    for key, at_tag, msg, typ, got in errs:
        if at_tag:
            if any(k[: len(key)] == key and (len(k) > len(key) or not t) for k, t, *_ in errs):
                continue
            if key in merged:
                merged[key][1].append(msg)
                continue
            merged[key] = [len(out), [msg]]
        out.append([key, msg, typ, got])
    for i, msgs in merged.values():
        out[i][1] = msgs[0] + "".join(f", or {m.removeprefix('Input should be ')}" for m in msgs[1:])
    problems = []
    for key, msg, typ, got in out:
        got_s = f" (got {shown(got)})" if typ != "missing" and not isinstance(got, (dict, list)) else ""
        if got_s and shown(got)[:40] in msg:  # the message names it already
            got_s = ""
        msg = msg if len(msg) <= 300 else msg[:300] + "…"
        problems.append(f"{path}:{_line_for(lines, key) or '?'}: {_key_text(key) or '(top level)'}: {msg}{got_s}")
    return problems


def _texts_read_as_values(mission: Mission, data: Any, texts: dict[tuple, tuple[bool, str]], lines: dict[tuple, int],
                          path: Path) -> list[str]:
    """Text that pydantic's lax mode turned into a number or a yes/no value: a quoted '1.2' or
    'no' (text to YAML: a value written as text is a mistake somewhere), or a plain 09 (a
    leading zero, octal elsewhere in YAML 1.1). Walks the file's data beside the validated
    mission, whose models are not strict (tuples come as YAML lists)."""
    problems: list[str] = []

    def walk(value: Any, given: Any, key: tuple) -> None:
        if isinstance(given, str):
            if isinstance(value, (bool, int, float)) and key in texts:
                quoted, text = texts[key]
                if quoted:
                    why = f"{'a yes/no value' if isinstance(value, bool) else 'a number'} is needed, not the quoted text {shown(text)}"
                else:
                    why = None if isinstance(value, bool) else _number_ambiguity(text)
                if why:
                    problems.append(f"{path}:{_line_for(lines, key) or '?'}: {_key_text(key)}: {why}")
        elif isinstance(given, dict):
            for k, v in given.items():
                if isinstance(value, BaseModel) and isinstance(k, str) and k in type(value).model_fields:
                    walk(getattr(value, k), v, key + (k,))
                elif isinstance(value, dict) and k in value:
                    walk(value[k], v, key + (k,))
        elif isinstance(given, list) and isinstance(value, (list, tuple)) and len(value) == len(given):
            for i, (m, g) in enumerate(zip(value, given)):
                walk(m, g, key + (i,))

    walk(mission, data, ())
    return problems


def _urdf_from_mission_dir(mission: Mission, path: Path) -> Mission:
    """A relative robot.arm.urdf is read from the mission file's directory, as field.prescan and
    drivers.zenoh.config_file are (it was read from the current directory)."""
    urdf = mission.robot.arm.urdf
    if not urdf or "\0" in urdf:  # none: the packaged URDF; a NUL: "not found" from RobotModel
        return mission
    p = Path(os.path.expanduser(urdf))
    if p.is_absolute():
        return mission
    arm = mission.robot.arm.model_copy(update={"urdf": str(path.resolve().parent / p)})
    return mission.model_copy(update={"robot": mission.robot.model_copy(update={"arm": arm})})


def load_mission(path: str | Path) -> tuple[Mission, list[TROI]]:
    """Parse and validate a mission file; returns the mission and its TROIs (listed or prescan)."""
    path = Path(path)
    if not path.is_file():
        raise MissionError([f"{path}: {not_a_file(path, 'mission')}"])
    try:
        size = path.stat().st_size
        if size > MAX_MISSION_BYTES:  # a mission is a few kB; long TROI lists belong in a prescan file
            raise MissionError([f"{path}: {size / 2**20:.1f} MiB is not a mission file (limit {MAX_MISSION_BYTES / 2**20:g} MiB; "
                                "put long TROI lists in field.prescan)"])
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise MissionError([f"{path}: cannot read: {e}"]) from e
    data, lines, texts, dups = _read_yaml(path, text)
    if not isinstance(data, dict):
        raise MissionError([f"{path}:1: the mission file must be a mapping of keys (robot, task, field, start, drivers, …)"])
    problems = [f"{path}:{d}" for d in dups]
    try:
        mission = Mission.model_validate(data)
    except ValidationError as e:
        raise MissionError(problems + _validation_problems(e, data, lines, path)) from e
    problems += _texts_read_as_values(mission, data, texts, lines, path)
    if problems:
        raise MissionError(problems)
    mission = _urdf_from_mission_dir(mission, path)
    mission._source, mission._lines = path, lines
    trois = _trois(mission, path, lines)
    _check_plan(mission, trois, path, lines)
    return mission, trois


def robot_model(mission: Mission):
    """The mission's RobotModel: its URDF, flange frame, joints and stow pose (ms; the maps are
    left to `run`). A problem is a MissionError on the key's line of the mission file."""
    from capm_field.robot_model import RobotModel

    try:
        return RobotModel(mission.robot)
    except UserError as e:  # "robot.arm.<key>: ..."
        key = str(e).split(":", 1)[0]
        loc = tuple(key.split(".")) if key.startswith("robot.") else ("robot",)
        raise MissionError([f"{mission.where(*loc)}: {e}"]) from e


def _bench_fuel_per_s() -> float:
    from sim_bench.sim_igniter import IgniterParams

    return IgniterParams().fuel_per_s


def _hold_rate(mission: Mission) -> tuple[float, str]:
    """The fuel rate a run will plan with from its start: the configured one, and on the bench at
    least the simulated igniter's own (0: not known before the first hold)."""
    rate, what = mission.igniter.fuel_per_s or 0.0, "igniter.fuel_per_s"
    if mission.drivers.kind == "bench" and _bench_fuel_per_s() > rate:
        rate, what = _bench_fuel_per_s(), "the bench igniter's rate"
    return rate, what


def fuel_warnings(mission: Mission, n_trois: int) -> list[str]:
    """A full tank that does not cover every target (the run warns of it at start, then stops
    before the first target that does not fit)."""
    rate, what = _hold_rate(mission)
    need = hold_fuel(mission.task.xi, rate)
    reserve = mission.igniter.fuel_reserve
    holds = holds_left(1.0, reserve, need)
    if 1 <= holds < n_trois:
        # each target needs `need` (the hold with its margin) above the reserve to begin, but a hold
        # burns need / FUEL_MARGIN at this rate: that many begin before the tank is that low
        # (an audit: "156 of 500" from `holds` alone, where the run flamed 195)
        burnt = need / FUEL_MARGIN
        expected = min(holds_left(1.0 - need + burnt, reserve, burnt), n_trois)
        about = "all" if expected >= n_trois else f"about {expected}"
        return [f"igniter: a full tank is enough for {about} of {n_trois} targets at {what} ({holds} if every hold burnt "
                f"its planned ~{need:.1%}, {FUEL_MARGIN - 1:.0%} above that rate; reserve {reserve:.1%}); "
                f"the run stops before the first that does not fit"]
    return []


def overlap_warnings(trois: list[TROI], shown_pairs: int = 3) -> list[str]:
    """TROIs whose discs overlap (centres closer than r_a + r_b): each one's look may find the same
    plant, the weed nearer the other's centre (the run skips a target whose centre it flamed already,
    `already_flamed`, but the weed that target was for is left)."""
    if len(trois) < 2:
        return []
    from scipy.spatial import cKDTree

    xy = np.array([t.xy for t in trois], float)
    r = np.array([t.r for t in trois], float)
    pairs = sorted((i, j) for i, j in cKDTree(xy).query_pairs(2.0 * float(r.max()))
                   if np.hypot(*(xy[i] - xy[j])) < r[i] + r[j])
    if not pairs:
        return []
    eg = "; ".join(f"{trois[i].id} and {trois[j].id}: centres {np.hypot(*(xy[i] - xy[j])):.2f} m apart, radii "
                   f"{r[i]:g} + {r[j]:g} m" for i, j in pairs[:shown_pairs])
    more = f" (and {len(pairs) - shown_pairs} more pairs)" if len(pairs) > shown_pairs else ""
    return [f"field: {len(pairs)} pair(s) of TROIs overlap — {eg}{more}: a look may find one plant for both; "
            "a target whose centre was flamed already is skipped (already_flamed) and its own weed left"]


def _check_plan(mission: Mission, trois: list[TROI], path: Path, lines: dict[tuple, int]) -> None:
    """What the schema cannot see but a run would only find out on the way: a bench fault
    schedule that does not parse, and a walk longer than the body can cover within its move
    timeout (coordinates in the wrong unit or frame, e.g. GeoJSON in lon/lat: the mission would
    flame the first targets, then abort on a move timeout)."""
    problems: list[str] = []
    if mission.drivers.kind == "bench" and mission.drivers.faults:
        from sim_bench.faults import bench_faults

        try:
            bench_faults(mission.drivers.faults, len(trois), mission.drivers.transport)
        except UserError as e:
            problems.append(f"{path}:{_line_for(lines, ('drivers', 'faults')) or '?'}: drivers.faults: {str(e).removeprefix('--faults: ')}")
    # a hold that can never begin: the run would abort at its first target (`holds_left`: the
    # executive's own rule, a full tank at start)
    rate, what = _hold_rate(mission)
    need = hold_fuel(mission.task.xi, rate)
    if holds_left(1.0, mission.igniter.fuel_reserve, need) < 1:
        problems.append(f"{path}:{_line_for(lines, ('igniter',)) or '?'}: igniter: a full tank cannot begin one hold: a hold needs "
                        f"~{need:.1%} ({FUEL_MARGIN} × task.xi {mission.task.xi:g} s × {rate:g}/s, {what}) and "
                        f"fuel_reserve {mission.igniter.fuel_reserve:.1%} is kept")
    from .ordering import order_trois

    start, end = mission.start.se2(), mission.end_pose()
    stops = [("start", start.xy)] + [(t.id, np.asarray(t.xy)) for t in order_trois(trois, start.xy, end.xy)] + [("end", end.xy)]
    max_leg = LEG_MARGIN * mission.robot.body.max_speed * mission.timeouts.get("body", 60.0)
    for (a, pa), (b, pb) in zip(stops, stops[1:]):
        d = float(np.hypot(*(np.asarray(pb, float) - np.asarray(pa, float))))
        if d > max_leg:
            problems.append(f"{path}: field: the walk from {a} to {b} is {d:.1f} m, more than the body covers in "
                            f"{LEG_MARGIN:.0%} of timeouts.body ({max_leg:.0f} m at {mission.robot.body.max_speed} m/s): "
                            "coordinates must be field-frame metres (a GeoJSON prescan in lon/lat?); for a longer walk raise timeouts.body")
            break
    if problems:
        raise MissionError(problems)


def _trois(mission: Mission, path: Path, lines: dict[tuple, int]) -> list[TROI]:
    if mission.field.prescan:
        src = (path.parent / mission.field.prescan).resolve()
        trois = load_prescan(src)
    else:
        # an entry without id is T<index in the file>, unless another entry is given that id
        trois = _fill_ids([TROI(t.x, t.y, t.r, t.id or "") for t in mission.field.trois])
    if not trois:
        raise MissionError([f"{path}:{_line_for(lines, ('field',)) or '?'}: field: no TROIs (list field.trois or give field.prescan)"])
    ids = [t.id for t in trois]
    dup = sorted(i for i, n in collections.Counter(ids).items() if n > 1)
    if dup:
        raise MissionError([f"{path}:{_line_for(lines, ('field',)) or '?'}: field: duplicate TROI ids {dup}"])
    return trois


class _DuplicateKey(ValueError):
    """A JSON object naming one key twice (json keeps the last silently)."""


def _json_object(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in pairs:
        if k in out:
            raise _DuplicateKey(k)
        out[k] = v
    return out


def _csv_number(text: str) -> float:
    """A CSV cell as a number: float()'s syntax without its digit-group underscores (`1_0` is 10 to
    Python, and ambiguous to a person, as the mission file's YAML numbers are)."""
    if "_" in text:
        raise ValueError(text)
    return float(text)


def load_prescan(src: Path) -> list[TROI]:
    """TROIs from a prescan file: CSV (x,y,r[,id]) or GeoJSON (Point features with radius|r)."""
    if not src.is_file():
        raise MissionError([f"{src}: {not_a_file(src, 'prescan')}"])
    problems: list[str] = []
    out: list[TROI] = []
    suffix = src.suffix.lower()
    if suffix not in (".csv", ".geojson", ".json"):
        raise MissionError([f"{src}: prescan must be .csv or .geojson"])
    try:
        if src.stat().st_size > MAX_PRESCAN_BYTES:  # MAX_TROIS rows are well under 1 MiB
            raise MissionError([f"{src}: {src.stat().st_size / 2**20:.0f} MiB is too large for a prescan file "
                                f"(limit {MAX_PRESCAN_BYTES // 2**20} MiB, {MAX_TROIS} TROIs)"])
        text = src.read_text(encoding="utf-8-sig")  # a spreadsheet's CSV may start with a BOM
    except (OSError, UnicodeDecodeError) as e:
        raise MissionError([f"{src}: cannot read the prescan file: {e}"]) from e
    if suffix == ".csv":
        try:
            reader = csv.DictReader(io.StringIO(text, newline=""))
            rows = list(reader)
        except csv.Error as e:
            raise MissionError([f"{src}: not a readable CSV file: {e}"]) from e
        header = reader.fieldnames or []
        twice = [h for h in ("x", "y", "r", "id") if header.count(h) > 1]
        if twice:  # DictReader keeps the last of two: which one the survey meant is not known
            raise MissionError([f"{src}:1: column {twice[0]!r} named twice in the header"])
        if not {"x", "y", "r"} <= set(header):
            raise MissionError([f"{src}:1: the first line must name the columns x, y, r (and optionally id); "
                                f"got {shown(','.join(header))}"])
        _check_count(src, len(rows))
        for i, row in enumerate(rows, start=2):
            try:
                x, y, r = _csv_number(row["x"]), _csv_number(row["y"]), _csv_number(row["r"])
            except (KeyError, TypeError, ValueError):
                problems.append(f"{src}:{i}: need numeric columns x, y, r (got {shown(row)})")
                continue
            out.append(_checked_troi(src, i, x, y, r, row.get("id") or "", problems))
    else:
        try:
            doc = json.loads(text, object_pairs_hook=_json_object)
        except _DuplicateKey as e:
            raise MissionError([f"{src}: key {shown(str(e))} given twice in one JSON object (which one the survey meant is not known)"]) from None
        except json.JSONDecodeError as e:
            raise MissionError([f"{src}:{e.lineno}: invalid JSON: {e.msg}"]) from e
        except RecursionError as e:
            raise MissionError([f"{src}: the JSON is nested too deeply to be a prescan file"]) from e
        except ValueError as e:  # an integer of over 4300 digits
            raise MissionError([f"{src}: invalid JSON: {e}"]) from e
        feats = doc.get("features") if isinstance(doc, dict) else None
        if not isinstance(feats, list):
            raise MissionError([f"{src}: expected a GeoJSON FeatureCollection"])
        _check_count(src, len(feats))
        for i, f in enumerate(feats):
            geom = f.get("geometry") if isinstance(f, dict) else None
            props = f.get("properties") if isinstance(f, dict) else None
            geom = geom if isinstance(geom, dict) else {}
            props = props if isinstance(props, dict) else {}
            coords = geom.get("coordinates")
            if geom.get("type") != "Point" or not isinstance(coords, list) or len(coords) < 2 \
                    or not all(_is_number(c) for c in coords[:2]):
                problems.append(f"{src}: features[{i}]: need a Point geometry with numeric coordinates")
                continue
            r = props.get("radius", props.get("r"))
            if not _is_number(r):
                problems.append(f"{src}: features[{i}].properties: need a numeric radius (or r)")
                continue
            try:
                x, y, r = float(coords[0]), float(coords[1]), float(r)
            except OverflowError:  # an integer of hundreds of digits
                problems.append(f"{src}: features[{i}]: coordinates and radius must be field-frame metres within "
                                f"±{FIELD_EXTENT:.0f} (got an integer of {max(len(str(abs(v))) for v in (*coords[:2], r) if isinstance(v, int))} digits)")
                continue
            tid = props.get("id")  # null and "" are no id, as in field.trois: a generated one
            tid = "" if tid is None else str(tid)
            out.append(_checked_troi(src, None, x, y, r, tid, problems, f"features[{i}]"))
    if problems:
        raise MissionError(problems)
    return _fill_ids(out)


def _fill_ids(trois: list[TROI]) -> list[TROI]:
    """TROIs without an id get T<index in the list>, or the next T<k> no listed TROI has."""
    used = {t.id for t in trois if t.id}
    out = []
    for i, t in enumerate(trois):
        if not t.id:
            k = i
            while f"T{k:02d}" in used:
                k += 1
            t = dataclasses.replace(t, id=f"T{k:02d}")
            used.add(t.id)
        out.append(t)
    return out


def _check_count(src: Path, n: int) -> None:
    if n > MAX_TROIS:
        raise MissionError([f"{src}: {n} TROIs, more than one mission takes ({MAX_TROIS}): split the field"])


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _checked_troi(src: Path, line: int | None, x: float, y: float, r: float, tid: str, problems: list[str], where: str = "") -> TROI:
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(r)) or not MIN_TROI_RADIUS <= r <= 0.5 \
            or max(abs(x), abs(y)) > FIELD_EXTENT:
        problems.append(f"{src}:{line or '?'}: {where + ': ' if where else ''}radius must be in [{MIN_TROI_RADIUS}, 0.5] m and "
                        f"coordinates finite field-frame metres within ±{FIELD_EXTENT:.0f} (got x={x}, y={y}, r={r})")
    try:
        _troi_id(tid)
    except ValueError as e:
        problems.append(f"{src}:{line or '?'}: {where + ': ' if where else ''}{e}")
    return TROI(x, y, r, tid)
