"""`capm-field review RUN.mcap [--rrd FILE] [--web] [--targets A-B] [--quiet]`: open a run log in Rerun.

Rerun loads the MCAP natively (transforms, URDF, image, calibration, text log); this module adds
what Rerun cannot draw from our custom protobuf messages, as Rerun archetypes in the `field`
frame: TROI discs, R_o / R_m annuli, planned and executed key states, detections (3D and on the
image), bench ground truth, the body's path, and igniter / energy time series. Then it lays
out a blueprint: 3D field | camera, igniter, energy, log.

Always goes through an .rrd file (`--rrd FILE`, else a temporary one): `rr.init(spawn=True)`
blocks and drops data headless (DEPENDENCY_NOTES), a file is exact and re-openable. The viewer
(native, or web on 127.0.0.1 with `--web`) is the `rerun` binary started directly, not the
Python wrapper, so the one child we start is the one we stop.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import subprocess
import sys
import tempfile
import uuid
import warnings
from array import array
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from rerun.chunk import McapReader, RrdReader

from capm_field.cli_args import count
from capm_field.cli_args import path as cli_path
from capm_field.errors import UserError, check_output, same_file, terminal_safe

from .review_parts import PART_TARGETS, Part, parse_targets, target_order
from .review_parts import select as select_part
from .runlog import PROTO_TOPICS, SCHEMAS, TOPICS
from .runlog_read import ReadReport, check_mcap, iter_run, salvage
from .runlog_schema import foreign_problem

TIMELINE = "message_log_time"  # the timeline Rerun's MCAP importer writes log_time to
FIELD = "field"
IMAGE_PLANE = "camera_image_plane"  # Rerun's frame for the image of a Foxglove CameraCalibration
_DURATION_LIMIT_NS = 10**17  # below ~1973: a monotonic or sim clock, shown as a duration
_TIME_MAX_NS = 2**63 - 1  # a timeline holds int64 ns; MCAP's log_time is uint64

COLORS = {
    "troi": (255, 215, 0),
    "ro": (66, 135, 245),
    "rm": (245, 130, 48),
    "plan": (160, 160, 160),
    "key_state": (0, 220, 220),
    "detection": (50, 220, 50),
    "truth": (230, 50, 230),
    "body_path": (120, 120, 255),
    "flame_on": (255, 60, 0),
    "armed": (255, 200, 0),
    "interlock_ok": (0, 180, 0),
    "fuel": (120, 120, 120),
    "estop": (200, 0, 0),
    "total": (66, 135, 245),
    "target_energy": (245, 130, 48),
}
_CUSTOM = {TOPICS[k] for k in ("plan", "key_state", "detection", "regions", "energy", "igniter", "truth_mpoi", "tf")}
# the schema each topic drawn here must carry: another one (a foreign or hand-made file) is skipped
_SCHEMAS = {t: SCHEMAS[t] for t in (*(TOPICS[k] for k in PROTO_TOPICS), TOPICS["tf"])}


def _part(target_id: str) -> str:
    """A target id as one Rerun entity-path part (ids may hold '/', spaces, dots: escaped)."""
    return rr.escape_entity_path_part(target_id or "_")


@dataclass
class RunData:
    """What the review draws itself, decoded from the custom topics."""

    first_ns: int | None = None
    last_ns: int | None = None
    messages: dict[str, list] = field(default_factory=lambda: defaultdict(list))  # topic -> [(t, msg)]
    body_path: list[tuple[float, float, float]] = field(default_factory=list)
    body_times: array = field(default_factory=lambda: array("q"))  # log time of each body_path point
    report: ReadReport = field(default_factory=ReadReport)
    imported: int | None = None  # messages handed to Rerun's MCAP importer (set by `write_rrd`)
    # every message read, by topic: log times and record places (`RunMessage.record`), to pick a part
    index: dict[str, tuple[array, array]] = field(default_factory=dict)
    part: Part | None = None  # set when only some of the run's targets are reviewed


def _body_poses(msg: Any) -> list[tuple[float, float, float]]:
    """field→body translations of a FrameTransforms message; TypeError/AttributeError when the
    file's FrameTransforms is not Foxglove's (checked here rather than against a descriptor)."""
    out = []
    for tf in msg.transforms:
        if tf.parent_frame_id == "field" and tf.child_frame_id == "body":
            p = (tf.translation.x, tf.translation.y, tf.translation.z)
            if not all(isinstance(v, float) for v in p):
                raise TypeError("translation is not three doubles")
            out.append(p)
    return out


def _bar(progress: bool, desc: str, unit: str, total: int | None = None):
    """A progress bar on stderr (a 1 000-target log takes ~20 s to review), or a silent one."""
    from tqdm import tqdm

    return tqdm(total=total, desc=f"capm-field review: {desc}", unit=unit, unit_scale=True, disable=not progress,
                file=sys.stderr, leave=False, mininterval=0.5)


def _counted(items, bar):
    for item in items:
        bar.update()
        yield item


def load_run(path: Path, progress: bool = False) -> RunData:
    data = RunData()
    checked: dict[Any, str | None] = {}  # decoded descriptor -> why it is not ours (None: it is)
    with _bar(progress, "reading the run log", "msg") as bar:
        for m in iter_run(path, report=data.report):
            if bar.total is None and data.report.expected_messages:
                bar.total = data.report.expected_messages
            bar.update()
            _take(data, m, checked)
    if data.report.messages == 0:
        why = f": {data.report.error}" if data.report.error else ""
        raise UserError(f"no readable messages in {path}{why}")
    return data


def _take(data: RunData, m: Any, checked: dict[Any, str | None]) -> None:
    """One message of the run log into `data` (or skipped, with the reason, into its report)."""
    want = _SCHEMAS.get(m.topic)
    why = want and foreign_problem(m.schema, m.data, want, checked)
    if why:
        data.report.skip(m.topic, why, m.record)
        return
    if m.log_time > _TIME_MAX_NS:  # np.datetime64 / Rerun timelines are int64 ns
        data.report.skip(m.topic, f"log_time {m.log_time} past 2**63 - 1 ns, beyond a Rerun timeline", m.record)
        return
    if m.topic == TOPICS["tf"]:
        try:
            poses = _body_poses(m.data)
        except (AttributeError, TypeError) as e:
            data.report.skip(m.topic, f"{want} with other fields: {type(e).__name__}: {e}", m.record)
            return
        data.body_path.extend(poses)
        data.body_times.extend([m.log_time] * len(poses))
    elif m.topic in _CUSTOM:
        data.messages[m.topic].append((m.log_time, m.data))
    times, records = data.index.setdefault(m.topic, (array("q"), array("q")))
    times.append(m.log_time)
    records.append(m.record)
    data.first_ns = m.log_time if data.first_ns is None else min(data.first_ns, m.log_time)
    data.last_ns = m.log_time if data.last_ns is None else max(data.last_ns, m.log_time)


# ---- geometry ----------------------------------------------------------------------------------
def circle(cx: float, cy: float, r: float, z: float = 0.01, n: int = 72) -> np.ndarray:
    a = np.linspace(0.0, 2.0 * math.pi, n + 1)
    return np.c_[cx + r * np.cos(a), cy + r * np.sin(a), np.full(n + 1, z)]


# ---- logging -----------------------------------------------------------------------------------
class _Logger:
    def __init__(self, rec: rr.RecordingStream, duration: bool, tick: Any = None) -> None:
        self.rec = rec
        self.duration = duration
        self._framed: set[str] = set()
        self._tick = tick  # called at every time set (progress)

    def at(self, t_ns: int) -> None:
        if self._tick is not None:
            self._tick()
        if self.duration:
            self.rec.set_time(TIMELINE, duration=np.timedelta64(int(t_ns), "ns"))
        else:
            self.rec.set_time(TIMELINE, timestamp=np.datetime64(int(t_ns), "ns"))

    def log(self, path: str, *archetypes, frame: str = FIELD, static: bool = False) -> None:
        if path not in self._framed:  # which named frame the entity lives in (Rerun ≥ 0.27), in the
            # entity's first row: a static row of its own was a second chunk per entity, and a
            # recording's chunk count is what Rerun's file index cannot hold beyond ~50 000
            archetypes = (rr.CoordinateFrame(frame), *archetypes)
            self._framed.add(path)
        self.rec.log(path, *archetypes, static=static)
        if any(isinstance(a, rr.Clear) for a in archetypes):
            self._framed.discard(path)  # a Clear hides what came before it, the frame too: the next row gives it again


def log_extras(rec: rr.RecordingStream, data: RunData, duration: bool, progress: bool = False) -> None:
    with _bar(progress, "drawing plans, regions, detections, plots", "msg", sum(len(v) for v in data.messages.values())) as bar:
        _log_extras(_Logger(rec, duration, bar.update), data)


def _log_extras(lg: _Logger, data: RunData) -> None:
    # each topic in time order (stable): an entity's frame rides in its first row, which must then
    # be its earliest (a foreign or hand-made log's messages may be out of order)
    msgs = defaultdict(list, {k: sorted(v, key=lambda tm: tm[0]) for k, v in data.messages.items()})
    t0 = data.first_ns or 0

    # TROIs: all of them from the run's start, so the field overview shows every weed.
    trois: dict[str, tuple[float, float, float]] = {}
    for topic in (TOPICS["plan"], TOPICS["regions"]):
        for _, m in msgs[topic]:
            if m.HasField("troi"):
                trois.setdefault(m.target_id or m.troi.id, (m.troi.x, m.troi.y, m.troi.r))
    # One entity for all the circles and one for all the centres (labelled by id): an entity per
    # target and kind made ~11 per target, and a 2 000-target run's recording more chunks than
    # Rerun's file index holds (the review failed, nothing written)
    lg.at(t0)
    if trois:
        xyr = np.array(list(trois.values()), float)
        lg.log("/review/troi", rr.LineStrips3D([circle(x, y, r) for x, y, r in xyr], colors=[COLORS["troi"]], radii=[0.004],
                                               labels=[f"TROI {tid}" for tid in trois]))
        lg.log("/review/troi/centres", rr.Points3D(np.c_[xyr[:, :2], np.full(len(xyr), 0.01)], colors=[COLORS["troi"]], radii=[0.01]))

    if data.body_path:
        lg.log("/review/body_path", rr.LineStrips3D([np.asarray(data.body_path)], colors=[COLORS["body_path"]], radii=[0.005]), static=True)

    for t, m in msgs[TOPICS["regions"]]:
        lg.at(t)
        tid = m.target_id
        ro = [circle(m.troi.x, m.troi.y, r, z=0.006) for a in m.ro for r in (a.r_inner, a.r_outer) if r > 0]
        lg.log(f"/review/regions/{_part(tid)}/R_o", rr.LineStrips3D(ro or [np.zeros((0, 3))], colors=[COLORS["ro"]], radii=[0.003]))
        # R_m around the MPOI once known, before that around X_w (the planners' assumption).
        cx, cy = (m.mpoi.x, m.mpoi.y) if m.HasField("mpoi") else (m.troi.x, m.troi.y)
        rm = [circle(cx, cy, r, z=0.008) for a in m.rm for r in (a.r_inner, a.r_outer) if r > 0]
        lg.log(f"/review/regions/{_part(tid)}/R_m", rr.LineStrips3D(rm or [np.zeros((0, 3))], colors=[COLORS["rm"]], radii=[0.003]))

    for t, m in msgs[TOPICS["plan"]]:
        lg.at(t)
        pts = [(m.start.x, m.start.y)] + [(k.body.x, k.body.y) for k in m.key_states] + [(m.end.x, m.end.y)]
        labels = ["start"] + [k.label for k in m.key_states] + ["end"]
        xyz = np.c_[np.asarray(pts), np.full(len(pts), 0.02)]
        path = f"/review/plan/{_part(m.target_id)}"
        lg.log(path, rr.LineStrips3D([xyz], colors=[COLORS["plan"]], radii=[0.004], labels=[f"{m.planner} p={m.p_upper:.2f} E={m.expected_cost:.1f}"]))
        lg.log(f"{path}/states", rr.Points3D(xyz, colors=[COLORS["plan"]] * len(xyz), radii=[0.02] * len(xyz), labels=labels))

    executed: dict[str, list] = defaultdict(list)
    for t, m in msgs[TOPICS["key_state"]]:
        lg.at(t)
        executed[m.target_id].append(m)
        ks = executed[m.target_id]
        xyz = np.array([(k.body.x, k.body.y, 0.03) for k in ks])
        labels = [k.label + (f" ({k.note})" if k.note else "") for k in ks]
        path = f"/review/key_states/{_part(m.target_id)}"
        lg.log(path, rr.Points3D(xyz, colors=[COLORS["key_state"]] * len(ks), radii=[0.03] * len(ks), labels=labels))
        lg.log(f"{path}/path", rr.LineStrips3D([xyz], colors=[COLORS["key_state"]], radii=[0.006]))
        if m.arm and m.HasField("target"):
            lg.log(f"{path}/aim", rr.Points3D([[m.target.x, m.target.y, 0.01]], colors=[COLORS["key_state"]], radii=[0.012], labels=[m.arm]))

    for t, m in msgs[TOPICS["detection"]]:
        lg.at(t)
        tid = m.target_id
        if m.HasField("mpoi_field"):
            lg.log(f"/review/detection/{_part(tid)}", rr.Points3D([[m.mpoi_field.x, m.mpoi_field.y, 0.01]], colors=[COLORS["detection"]], radii=[0.015], labels=[f"MPOI {m.confidence:.2f}"]))
        # absent in older logs; a foreign file's non-finite or float32-overflowing points are left out
        rim = [(p.x, p.y) for p in getattr(m, "roi_rim", ()) if abs(p.x) < 1e9 and abs(p.y) < 1e9]
        if len(rim) >= 3:  # the ROI the detector searched, as it lay on the raw image
            lg.log("/camera/image/roi", rr.LineStrips2D([rim + rim[:1]], colors=[COLORS["troi"]], radii=[1.5], labels=[f"ROI {tid}"]), frame=IMAGE_PLANE)
        else:
            lg.log("/camera/image/roi", rr.Clear(recursive=False), frame=IMAGE_PLANE)
        if m.HasField("pixel"):
            lg.log("/camera/image/detection", rr.Points2D([[m.pixel.x, m.pixel.y]], colors=[COLORS["detection"]], radii=[8.0], labels=[f"{tid} {m.confidence:.2f}"]), frame=IMAGE_PLANE)
        else:
            lg.log("/camera/image/detection", rr.Clear(recursive=False), frame=IMAGE_PLANE)
            lg.log(f"/review/detection/{_part(tid)}/miss", rr.TextLog(f"{tid}: no MPOI ({m.reason or 'no reason'})", level="WARN"))

    # the bench's true centres, all in one entity (logged together at the run's start): at each
    # time one is given, every one given so far
    truth: dict[str, tuple[float, float]] = {}
    given = msgs[TOPICS["truth_mpoi"]]
    for i, (t, m) in enumerate(given):
        truth[m.target_id] = (m.mpoi.x, m.mpoi.y)
        if i + 1 == len(given) or given[i + 1][0] != t:
            lg.at(t)
            xy = np.array(list(truth.values()), float)
            lg.log("/review/truth", rr.Points3D(np.c_[xy, np.full(len(xy), 0.012)], colors=[COLORS["truth"]], radii=[0.012],
                                                labels=[f"truth {k}" for k in truth]))

    _series(lg, msgs)


def _series(lg: _Logger, msgs: dict[str, list]) -> None:
    rec = lg.rec
    step = rr.components.InterpolationMode.StepAfter
    for name in ("flame_on", "armed", "interlock_ok", "estop", "fuel"):
        rec.log(f"/plots/igniter/{name}", rr.SeriesLines(colors=[COLORS[name]], names=[name], widths=[2.0], interpolation_mode=step if name != "fuel" else None), static=True)
    for name in ("total", "target_energy"):
        rec.log(f"/plots/energy/{name}", rr.SeriesLines(colors=[COLORS[name]], names=[name], widths=[2.0]), static=True)
    rec.log("/plots/energy/body_moves", rr.SeriesPoints(colors=[(90, 90, 90)], names=["body_moves"], marker_sizes=[3.0]), static=True)
    for t, m in msgs[TOPICS["igniter"]]:
        lg.at(t)
        for name in ("flame_on", "armed", "interlock_ok", "estop"):
            rec.log(f"/plots/igniter/{name}", rr.Scalars([float(getattr(m, name))]))
        rec.log("/plots/igniter/fuel", rr.Scalars([m.fuel]))
    for t, m in msgs[TOPICS["energy"]]:
        lg.at(t)
        rec.log("/plots/energy/total", rr.Scalars([m.total]))
        rec.log("/plots/energy/target_energy", rr.Scalars([m.target_energy]))
        rec.log("/plots/energy/body_moves", rr.Scalars([float(m.body_moves)]))


def blueprint() -> rrb.Blueprint:
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(
                name="Field",
                origin="/",
                contents=["/**", "- /plots/**"],
                spatial_information=rrb.SpatialInformation(target_frame=FIELD, show_axes=True),
            ),
            rrb.Vertical(
                rrb.Spatial2DView(name="Camera", origin="/camera/image"),
                rrb.TimeSeriesView(name="Igniter (1 = on/true)", origin="/plots/igniter"),
                rrb.TimeSeriesView(name="Energy", origin="/plots/energy"),
                rrb.TextLogView(name="Log", contents=["/log/**", "/review/**"]),
                row_shares=[3, 2, 2, 2],
            ),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(timeline=TIMELINE, expanded=True),
        collapse_panels=False,
    )


def _urdf_package_path() -> str | None:
    """Where `package://example-robot-data/...` (the Z1 meshes) resolves, for Rerun's importer."""
    try:
        from capm_field.robot_model import default_urdf_path

        share = default_urdf_path().parents[4]  # .../share/example-robot-data/robots/z1_description/urdf
        return str(share) if (share / "example-robot-data").is_dir() else None
    except Exception:  # noqa: BLE001 - meshes are a nicety; the arm still animates as frames
        return None


def write_rrd(mcap: Path, out: Path, data: RunData | None = None, progress: bool = False) -> RunData:
    """Convert the run to an .rrd: native MCAP import + our archetypes + blueprint.

    Written to a temporary file beside `out` and renamed over it only once complete, so a
    review that fails half-way leaves an existing `out` (a good earlier .rrd) as it was."""
    data = data or load_run(mcap)
    duration = (data.first_ns or 0) < _DURATION_LIMIT_NS
    pkg = _urdf_package_path()
    if pkg and "ROS_PACKAGE_PATH" not in os.environ:
        os.environ["ROS_PACKAGE_PATH"] = pkg
    if out.exists() and not out.is_file():  # a device or FIFO: the rename below would replace the node itself
        raise UserError(f"--rrd {out}: exists and is not a regular file")
    out.parent.mkdir(parents=True, exist_ok=True)
    # same directory: the rename is atomic; Rerun creates the file itself (umask permissions). A
    # short name: `out`'s own may already be near the file system's 255-byte limit
    part = out.with_name(f".rrd-{uuid.uuid4().hex[:12]}.part")
    rec = rr.RecordingStream("capm_field_review", recording_id=str(uuid.uuid4()))
    try:
        try:
            rec.save(str(part), default_blueprint=blueprint())
        except Exception as e:  # noqa: BLE001 - Rerun reports a file it cannot create as a RuntimeError
            raise UserError(f"--rrd {out}: cannot write it: {e}") from None
        with tempfile.TemporaryDirectory(prefix="capm-review-") as tmp:
            source = mcap
            rep = data.report
            if data.part or not rep.complete or rep.damaged or not rep.has_summary or rep.skipped_records:
                # A crash or damaged file: Rerun's own recovery (recover=True) drops channels whose
                # message index was torn, so hand it a finalised copy of exactly what our reader read.
                # Payloads we could not decode are left out: on one, Rerun's importer logs an error
                # and its file sink then fails to finish the recording (no footer: unreadable).
                # A part of a long run (`--targets`) is such a copy of the part's messages only.
                source = Path(tmp) / "salvaged.mcap"
                keep = data.part.keep if data.part else None
                what = "copying the part" if data.part else "copying what was read"
                with _bar(progress, what, "msg", rep.records or None) as bar:
                    data.imported = salvage(mcap, source, drop=rep.skipped_records, keep=keep, tick=bar.update).messages
            else:
                data.imported = rep.messages
            try:
                reader = McapReader(str(source), recover=True, timeline_type="duration_ns" if duration else "timestamp_ns")
                with _bar(progress, "Rerun's import", "chunk") as bar:
                    rr.send_chunks(_counted(reader.stream(), bar), recording=rec)
            except Exception as e:  # noqa: BLE001 - the Rust reader's errors are plain exceptions
                raise UserError(f"Rerun cannot read {mcap}: {e}") from e
        which = f" (targets {data.part.first}–{data.part.last})" if data.part else ""
        rec.send_recording_name(mcap.parent.name + "/" + mcap.name + which)
        log_extras(rec, data, duration, progress)
        rec.flush()
        rec.disconnect()
        _check_rrd(part, out, len(data.part.ids) if data.part else len(target_order(data)[0]))
        os.replace(part, out)
    except BaseException:  # incl. Ctrl-C: the partial recording goes, `out` is untouched
        rec.disconnect()
        try:
            part.unlink(missing_ok=True)
        except OSError:  # (never created: its directory refused it) the first error is the one to see
            pass
        raise
    return data


def _check_rrd(part: Path, out: Path, targets: int = 0) -> None:
    """Rerun's file sink reports a recording it could not finish only in its log, so open the
    written file's manifest (written last, ~40 ms) before it replaces `out`. `targets`: how many the
    recording holds (over ~1 000, the hint to review fewer at once)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "no footer/manifest": the error below says it
            RrdReader(part).store()
    except Exception as e:  # noqa: BLE001 - the Rust reader's errors are plain exceptions
        why = ("no footer: its file sink failed to end the stream, see Rerun's error above" if "footer" in str(e)
               else " ".join(str(e).replace(str(part), "").split())[:200])
        hint = f"; {targets} targets: review fewer at once with --targets A-B (docs/log.md)" if targets > 1000 else ""
        raise UserError(f"--rrd {out}: Rerun did not finish the recording ({why}); nothing written{hint}") from None


def _check_rrd_is_not_the_log(run: str, rrd: Path) -> None:
    """--rrd naming the run log itself (or the run directory's run.mcap) would overwrite the log."""
    p = Path(run)
    log = p / "run.mcap" if p.is_dir() else p
    if log.exists() and same_file(log, rrd):  # (a missing log: check_mcap says so)
        raise UserError(f"--rrd {rrd} is the run log being reviewed ({log}); name another file")


# ---- viewers -----------------------------------------------------------------------------------
def _rerun_binary() -> str:
    import rerun_cli

    exe = Path(rerun_cli.__file__).parent / ("rerun.exe" if sys.platform.startswith("win") else "rerun")
    if not exe.is_file():
        raise UserError(f"the Rerun viewer binary is missing: {exe} (reinstall rerun-sdk)")
    return str(exe)


def _run_child(cmd: list[str]) -> int:
    """Run the viewer until it exits, Ctrl-C or SIGTERM; then stop it and its process group (ours)."""

    def _terminate(signum, frame):  # SIGTERM → the same clean path as Ctrl-C
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, _terminate)
    proc = subprocess.Popen(cmd, start_new_session=True)
    try:
        return proc.wait()
    except KeyboardInterrupt:
        return 0
    finally:
        signal.signal(signal.SIGTERM, previous)
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGTERM)  # the group we created for this child only
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()


# a TCP port, 1–65535 (0 would let the viewer pick one, and the address printed would be wrong)
_port = count(1, 65535)


def _part_of(data: RunData, targets: tuple[int, int] | None) -> RunData:
    """The part of the run to review: `--targets`, else the whole run up to PART_TARGETS targets,
    else its first PART_TARGETS (said on stderr, with the option for the next part)."""
    if targets is None:
        n = len(target_order(data)[0])
        if n <= PART_TARGETS:
            return data
        targets = (0, PART_TARGETS - 1)
        print(f"capm-field review: note: the run holds {n} targets, more than Rerun shows at once (docs/log.md): "
              f"reviewing targets 0–{PART_TARGETS - 1}; --targets {PART_TARGETS}-{min(n, 2 * PART_TARGETS) - 1} for the next part",
              file=sys.stderr)
    sub, part = select_part(data, *targets)
    print(terminal_safe(f"capm-field review: {part.describe()}"), file=sys.stderr)
    return sub


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="capm-field review", description=__doc__.splitlines()[0])
    ap.add_argument("run", type=cli_path, help="run log (run.mcap) or its run directory, also one cut short by a crash")
    ap.add_argument("--rrd", help="write a Rerun recording to this file (headless, no viewer)")
    ap.add_argument("--targets", metavar="A-B", type=parse_targets,
                    help=f"review only the targets at positions A..B (0-based, in the order the run began them); "
                         f"a run of more than {PART_TARGETS} is reviewed {PART_TARGETS} at a time, the first part by default")
    ap.add_argument("--web", action="store_true", help="serve the web viewer on 127.0.0.1 instead of the native viewer")
    ap.add_argument("--quiet", action="store_true", help="no progress bars (shown on a terminal only)")
    ap.add_argument("--web-port", type=_port, default=9090, help="HTTP port of the web viewer (default 9090)")
    ap.add_argument("--grpc-port", type=_port, default=9876, help="gRPC port the web viewer reads from (default 9876)")
    args = ap.parse_args(argv)
    if args.web and args.web_port == args.grpc_port:  # the viewer failed on its own after we printed its address
        raise UserError(f"--web-port and --grpc-port must differ (both {args.web_port})")

    if args.rrd is not None:
        if not args.rrd:  # Path("") would be ".", the current directory
            raise UserError("--rrd: empty file name")
        args.rrd = Path(args.rrd)
        _check_rrd_is_not_the_log(args.run, args.rrd)  # before anything is opened
    mcap = check_mcap(args.run)
    check_output(str(args.rrd) if args.rrd else None, "--rrd")  # before the read, not after it
    native = not args.rrd and not args.web
    if native and sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise UserError("no display for the native viewer (DISPLAY/WAYLAND_DISPLAY unset): use --rrd FILE or --web")
    progress = not args.quiet and sys.stderr.isatty()
    data = load_run(mcap, progress)
    rep = data.report
    for note in rep.notes(mcap):
        print(f"capm-field review: note: {terminal_safe(note)}", file=sys.stderr)
    data = _part_of(data, args.targets)
    if args.rrd and not args.web:
        write_rrd(mcap, args.rrd, data, progress)
        skipped = f"; {rep.undecodable} skipped, see the note above" if rep.undecodable else ""
        part = f"; {data.part.describe()}" if data.part else ""
        print(terminal_safe(f"wrote {args.rrd} ({data.imported} messages{skipped}{part})"))
        return 0

    with tempfile.TemporaryDirectory(prefix="capm-review-") as tmp:
        out = args.rrd or Path(tmp) / "run.rrd"
        write_rrd(mcap, out, data, progress)
        if args.web:
            url = f"rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{args.grpc_port}%2Fproxy"
            print(f"web viewer (loopback only): http://127.0.0.1:{args.web_port}/?url={url}  (Ctrl-C to stop)", flush=True)
            cmd = [_rerun_binary(), "--web-viewer", "--bind", "127.0.0.1", "--port", str(args.grpc_port), "--web-viewer-port", str(args.web_port), str(out)]
        else:
            # The native viewer also hosts a gRPC server (0.0.0.0 by default): keep it on loopback.
            cmd = [_rerun_binary(), "--bind", "127.0.0.1", str(out)]
        return _run_child(cmd)
