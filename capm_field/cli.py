"""`capm-field` command line: one dispatcher, each sub-command in its own module.

Sub-commands are looked up by module path and imported only when run, so `capm_field` has no
static import of `mission`, `drivers` or `sim_bench` (dependencies point one way, DESIGN.md).
Each module exposes `main(argv: list[str]) -> int` with its own argparse parser.

Errors a user can cause (UserError, config validation) print one line and exit 2, no traceback.
"""

from __future__ import annotations

import importlib
import os
import sys

from .errors import UserError, shown, terminal_safe

COMMANDS: dict[str, tuple[str, str]] = {
    "run": ("mission.run_cli", "run a mission file (bench or hardware) and write run.mcap + summary.json"),
    "validate": ("mission.run_cli:validate_main", "check a mission file without running it"),
    "review": ("mission.review", "open a run log (MCAP) in Rerun"),
    "bench": ("capm_field.bench", "planner bench: reproduce the paper's Table I"),
    "bench-fields": ("capm_field.fields_bench", "whole fields: per-target planners vs the field planner and the oracle"),
    "bench-mission": ("mission.bench_mission", "planner bench on a mission's geometry (check a run against it)"),
    "regions": ("capm_field.regions_plot", "draw R_o, R_m and their overlap to a PNG"),
    "detect": ("capm_field.detect_cli", "the weed-centre detector on image files (photos, saved frames)"),
    "detect-replay": ("mission.detect_replay", "a run log's images through today's detector, against the logged answers"),
    "bench-perception": ("sim_bench.perception_bench", "detector accuracy and latency on rendered scenes"),
    "bench-drivers": ("sim_bench.drivers_bench", "zenoh and CAN transport figures on loopback"),
    "spot-bridge": ("drivers.spot_bridge", "serve the zenoh body protocol on Spot's payload computer"),
}


def _usage() -> str:
    lines = ["usage: capm-field <command> [options]", "", "commands:"]
    lines += [f"  {name:<18}{help_}" for name, (_, help_) in COMMANDS.items()]
    lines += ["", "capm-field <command> --help for the options of a command"]
    return "\n".join(lines)


def _load(target: str):
    module, _, func = target.partition(":")
    return getattr(importlib.import_module(module), func or "main")


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(_usage())
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"capm-field: error: unknown command {name!r}; choose from {', '.join(COMMANDS)}", file=sys.stderr)
        return 2
    try:
        entry = _load(COMMANDS[name][0])
    except ModuleNotFoundError as e:
        print(f"capm-field: error: command {name!r} is not available in this build ({e.name} missing)", file=sys.stderr)
        return 2
    try:
        return int(entry(rest) or 0)
    except UserError as e:
        # one line per problem (a MissionError reports several), each escaped on its own
        for line in getattr(e, "problems", None) or [str(e)]:
            print(f"capm-field {name}: error: {terminal_safe(line)}", file=sys.stderr)
        return 2
    except OSError as e:
        if e.filename is None:
            raise  # not a path the user gave: a fault to see whole
        # a path the checks before could not judge (a name over the file system's limit, a
        # device, /proc): one line naming it, as for any bad input
        print(f"capm-field {name}: error: {shown(os.fsdecode(e.filename) if isinstance(e.filename, (str, bytes)) else str(e.filename), 120)}: {e.strerror or e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"capm-field {name}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
