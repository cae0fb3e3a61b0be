"""Mission file: one YAML document → a validated `Mission` (pydantic), or every problem at once.

Each problem is reported as `FILE:LINE: key.path: message`, using the YAML node marks, and the
loader raises `MissionError` (exit 2, nothing started, nothing written). Unknown keys are errors.
TROIs are listed under `field.trois` or loaded from a prescan file (`field.prescan`: CSV with
columns x,y,r[,id] or GeoJSON Points with a `radius`/`r` property, field-frame metres).
"""

from __future__ import annotations

import collections
import csv
import io
import json
import math
import re
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import yaml
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, field_validator, model_validator

from capm_field.config import RobotConfig, StrictNumbers, TaskConfig, not_bool
from capm_field.errors import UserError
from capm_field.geometry import FIELD_EXTENT_M as FIELD_EXTENT
from capm_field.geometry import SE2
from capm_field.keystates import TROI

PLANNER_NAMES = ("a", "b", "c", "cstar", "field")
MAX_MISSION_BYTES = 4 * 2**20
MAX_PRESCAN_BYTES = 16 * 2**20
MAX_TROIS = 5000  # ~14 h of flaming at ~10 s a weed; ordering them alone takes ~9 s
MAX_TIMEOUT_S = 3600.0
# ids name log lines, summary keys and (escaped) Rerun paths: any printable text of 1–64 characters
# (a prescan tool's "W 12" or "plot A/3" too), not starting or ending with a space
TROI_ID_RE = re.compile(r"^(?=.{1,64}\Z)[^\x00-\x20\x7f-\x9f](?:[^\x00-\x1f\x7f-\x9f]*[^\x00-\x20\x7f-\x9f])?\Z")
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


def _troi_id(v: str | None) -> str | None:
    if v is not None and v != "" and not TROI_ID_RE.match(v):  # "" (or none): a generated id
        raise ValueError(f"a TROI id is 1-64 printable characters, no control characters, no space at either end (got {v[:80]!r})")
    return v or None


class TroiSpec(_Strict):
    id: str | None = None
    x: Coord
    y: Coord
    r: float = Field(gt=0.0, le=0.5, description="TROI radius r_w (m)")

    @field_validator("id")
    @classmethod
    def _id(cls, v: str | None) -> str | None:
        return _troi_id(v)


class FieldSpec(_Strict):
    trois: list[TroiSpec] = Field(default_factory=list, max_length=MAX_TROIS)
    prescan: str | None = Field(None, description="CSV or GeoJSON file of TROI centres and radii")

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
    seed: Annotated[int, BeforeValidator(not_bool)] = Field(0, ge=0)
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
            raise ValueError(f"a zenoh endpoint is <protocol>/<address>, e.g. tls/192.168.80.3:7447 (got {bad[0]!r})")
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
            raise ValueError(f"unknown python-can interface {v!r} (socketcan on the robot)")
        return v


class CameraSpec(_Strict):
    source: str | int = 0


class HardwareDrivers(_Tagged):
    kind: Literal["hardware"]
    zenoh: ZenohSpec = Field(default_factory=ZenohSpec)
    can: CanSpec = Field(default_factory=CanSpec)
    camera: CameraSpec = Field(default_factory=CameraSpec)


FUEL_RESERVE = 0.02  # tank fraction never planned into by default


class IgniterSpec(_Strict):
    """Fuel budget: a target is begun only if its ξ hold fits above `fuel_reserve`."""

    fuel_per_s: float | None = Field(None, gt=0.0, le=1.0, description="tank fraction burnt per second of flame; "
                                     "unset: measured from the run's own holds (none known before the first)")
    fuel_reserve: float = Field(FUEL_RESERVE, ge=0.0, lt=1.0, description="tank fraction never planned into")


class OutputSpec(_Strict):
    dir: str = "runs/latest"
    images: bool = True

    @field_validator("dir")
    @classmethod
    def _dir(cls, v: str) -> str:
        if not v.strip() or "\0" in v:  # "" would write into the current directory
            raise ValueError("needs a directory name")
        return v


class Mission(_Strict):
    name: str = "mission"
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

    @field_validator("planner")
    @classmethod
    def _planner(cls, v: str) -> str:
        if v not in PLANNER_NAMES:
            raise ValueError(f"unknown planner {v!r}; choose from {', '.join(PLANNER_NAMES)}")
        return v

    def end_pose(self) -> SE2:
        return (self.end or self.start).se2()


# ---------------------------------------------------------------------------------------------
def _line_map(text: str, duplicates: list[str] | None = None) -> dict[tuple, int]:
    """Key path → 1-based line of the node, from the YAML composition tree. Keys given twice in
    one mapping (YAML would silently keep the last) are appended to `duplicates`."""
    out: dict[tuple, int] = {}

    seen_nodes: set[int] = set()

    def walk(node, path: tuple) -> None:
        out[path] = node.start_mark.line + 1
        if id(node) in seen_nodes:  # an alias: its lines were mapped where it was anchored
            return
        seen_nodes.add(id(node))
        if isinstance(node, yaml.MappingNode):
            seen: dict = {}
            for k, v in node.value:
                # a complex key (`? [a, b]`) is unhashable: name it by its line, pydantic refuses it
                key = k.value if isinstance(k, yaml.ScalarNode) else f"<key on line {k.start_mark.line + 1}>"
                if duplicates is not None and key in seen:
                    where = ".".join(str(x) for x in path + (key,))
                    duplicates.append(f"{k.start_mark.line + 1}: {where}: key given twice (first on line {seen[key]})")
                seen.setdefault(key, k.start_mark.line + 1)
                out[path + (key,)] = k.start_mark.line + 1
                walk(v, path + (key,))
        elif isinstance(node, yaml.SequenceNode):
            for i, v in enumerate(node.value):
                walk(v, path + (i,))

    root = yaml.compose(text, Loader=yaml.SafeLoader)
    if root is not None:
        _check_expansion(root)
        walk(root, ())
    return out


MAX_NODES = 1_000_000  # YAML nodes after aliases are expanded (a mission of 10⁵ TROIs has ~6·10⁵)


class _Expansion(ValueError):
    pass


def _check_expansion(root) -> None:
    """Refuse an alias that contains itself and alias "bombs" (a few lines that expand to
    billions of nodes, which validation would then walk): count the nodes aliases expand to."""
    size: dict[int, int] = {}
    open_: set[int] = set()

    def count(node) -> int:
        k = id(node)
        if k in size:
            return size[k]
        if k in open_:
            raise _Expansion(f"line {node.start_mark.line + 1}: a YAML alias refers to a node that contains it")
        open_.add(k)
        kids = [x for kv in node.value for x in kv] if isinstance(node, yaml.MappingNode) else \
            node.value if isinstance(node, yaml.SequenceNode) else []
        n = 1
        for c in kids:
            n += count(c)
            if n > MAX_NODES:
                raise _Expansion(f"line {node.start_mark.line + 1}: YAML aliases expand to more than {MAX_NODES} nodes")
        open_.discard(k)
        size[k] = n
        return n

    count(root)


def _line_for(lines: dict[tuple, int], loc: tuple) -> int | None:
    loc = tuple(x for x in loc if not (isinstance(x, str) and x in ("bench", "hardware", "function-after", "function-before")))
    while loc:
        if loc in lines:
            return lines[loc]
        loc = loc[:-1]
    return lines.get(())


def load_mission(path: str | Path) -> tuple[Mission, list[TROI]]:
    """Parse and validate a mission file; returns the mission and its TROIs (listed or prescan)."""
    path = Path(path)
    if not path.is_file():
        raise MissionError([f"{path}: {_not_a_file(path, 'mission')}"])
    try:
        size = path.stat().st_size
        if size > MAX_MISSION_BYTES:  # a mission is a few kB; long TROI lists belong in a prescan file
            raise MissionError([f"{path}: {size / 2**20:.0f} MiB is not a mission file (limit {MAX_MISSION_BYTES // 2**20} MiB; "
                                "put long TROI lists in field.prescan)"])
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise MissionError([f"{path}: cannot read: {e}"]) from e
    dups: list[str] = []
    try:
        lines = _line_map(text, dups)  # first: it refuses self-referring and exploding aliases
        data = yaml.safe_load(text)
    except _Expansion as e:
        raise MissionError([f"{path}: {e}"]) from e
    except RecursionError as e:  # PyYAML composes nested nodes recursively
        raise MissionError([f"{path}: the YAML is nested too deeply to be a mission file"]) from e
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark else str(path)
        raise MissionError([f"{where}: YAML syntax error: {getattr(e, 'problem', None) or e}"]) from e
    if not isinstance(data, dict):
        raise MissionError([f"{path}:1: the mission file must be a mapping of keys (robot, task, field, start, drivers, …)"])
    problems = [f"{path}:{d}" for d in dups]
    try:
        mission = Mission.model_validate(data)
    except ValidationError as e:
        for err in e.errors():
            loc = tuple(err["loc"])
            line = _line_for(lines, loc)
            key = ".".join(str(x) for x in loc if x not in ("bench", "hardware", "[key]")) or "(top level)"
            msg = err["msg"].removeprefix("Value error, ")
            got = err.get("input")
            got_s = f" (got {got!r})" if err["type"] not in ("missing",) and not isinstance(got, (dict, list)) else ""
            if got_s and f"{got!r}"[:40] in msg:  # the message names it already
                got_s = ""
            problems.append(f"{path}:{line or '?'}: {key}: {msg}{got_s}")
        raise MissionError(problems) from e
    if problems:
        raise MissionError(problems)
    trois = _trois(mission, path, lines)
    _check_plan(mission, trois, path, lines)
    return mission, trois


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
        used = {t.id for t in mission.field.trois if t.id}
        trois = []
        for i, t in enumerate(mission.field.trois):
            tid = t.id
            if not tid:
                k = i
                while f"T{k:02d}" in used:
                    k += 1
                tid = f"T{k:02d}"
                used.add(tid)
            trois.append(TROI(t.x, t.y, t.r, tid))
    if not trois:
        raise MissionError([f"{path}:{_line_for(lines, ('field',)) or '?'}: field: no TROIs (list field.trois or give field.prescan)"])
    ids = [t.id for t in trois]
    dup = sorted(i for i, n in collections.Counter(ids).items() if n > 1)
    if dup:
        raise MissionError([f"{path}:{_line_for(lines, ('field',)) or '?'}: field: duplicate TROI ids {dup}"])
    return trois


def load_prescan(src: Path) -> list[TROI]:
    """TROIs from a prescan file: CSV (x,y,r[,id]) or GeoJSON (Point features with radius|r)."""
    if not src.is_file():
        raise MissionError([f"{src}: {_not_a_file(src, 'prescan')}"])
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
            rows = list(csv.DictReader(io.StringIO(text, newline="")))
        except csv.Error as e:
            raise MissionError([f"{src}: not a readable CSV file: {e}"]) from e
        _check_count(src, len(rows))
        for i, row in enumerate(rows, start=2):
            try:
                x, y, r = float(row["x"]), float(row["y"]), float(row["r"])
            except (KeyError, TypeError, ValueError):
                problems.append(f"{src}:{i}: need numeric columns x, y, r (got {row})")
                continue
            out.append(_checked_troi(src, i, x, y, r, row.get("id") or f"T{len(out):02d}", problems))
    else:
        try:
            doc = json.loads(text)
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
            x, y = (float(c) for c in coords[:2])
            out.append(_checked_troi(src, None, x, y, float(r), str(props.get("id", f"T{len(out):02d}")), problems, f"features[{i}]"))
    if problems:
        raise MissionError(problems)
    return out


def _check_count(src: Path, n: int) -> None:
    if n > MAX_TROIS:
        raise MissionError([f"{src}: {n} TROIs, more than one mission takes ({MAX_TROIS}): split the field"])


def _not_a_file(p: Path, what: str) -> str:
    """Why `p` (not `is_file()`) cannot be read as a `what` file."""
    return f"is a directory, not a {what} file" if p.is_dir() else f"{what} file not found" if not p.exists() else "not a regular file"


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _checked_troi(src: Path, line: int | None, x: float, y: float, r: float, tid: str, problems: list[str], where: str = "") -> TROI:
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(r)) or not 0 < r <= 0.5 \
            or max(abs(x), abs(y)) > FIELD_EXTENT:
        problems.append(f"{src}:{line or '?'}: {where + ': ' if where else ''}radius must be in (0, 0.5] m and "
                        f"coordinates finite field-frame metres within ±{FIELD_EXTENT:.0f} (got x={x}, y={y}, r={r})")
    try:
        _troi_id(tid)
    except ValueError as e:
        problems.append(f"{src}:{line or '?'}: {where + ': ' if where else ''}{e}")
    return TROI(x, y, r, tid)
