"""Errors a user can cause. The CLI prints them as one line and exits with code 2."""

import math
import os
import reprlib
import sys
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

SHOWN = 80  # characters of a bad value quoted in an error line


class UserError(Exception):
    """A bad input (file, value, option) — reported as one clear line naming the value, exit 2."""


_BOUNDED = reprlib.Repr()  # (keyword arguments only from Python 3.12)
_BOUNDED.maxlevel = 3
_BOUNDED.maxlist = _BOUNDED.maxtuple = _BOUNDED.maxdict = _BOUNDED.maxset = _BOUNDED.maxfrozenset = 6
_BOUNDED.maxstring = _BOUNDED.maxlong = _BOUNDED.maxother = SHOWN


def shown(value: Any, limit: int = SHOWN) -> str:
    """A bad value for an error line: its repr cut to about `limit` characters (a 200 kB value was
    echoed whole). An integer of over 1 000 bits is described by its size: a CBOR or JSON bignum of
    thousands of digits has no decimal text within Python's int-to-text limit."""
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 1000:
        return f"<an integer of {value.bit_length()} bits>"
    if isinstance(value, str) and len(value) > limit:
        return f"{value[:limit]!r}…"
    try:
        # containers through reprlib's bounded walk: a decoded value may share parts (2^n leaves
        # in a few hundred bytes), and a full repr of it would never end
        text = _BOUNDED.repr(value) if isinstance(value, (list, tuple, dict, set, frozenset)) else repr(value)
    except Exception:  # noqa: BLE001 - any value a decoder can make must be describable
        return f"<a {type(value).__name__}>"
    return text if len(text) <= limit + 2 else text[:limit] + "…"


def terminal_safe(text: str) -> str:
    """`text` with every character that is not printable (escape sequences, newlines, NUL: from
    a log or file name someone else wrote) shown as its Python escape, so a line printed to a
    terminal stays one line and cannot clear or rewrite the screen."""
    return text if text.isprintable() else "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def finite_real(v: Any) -> bool:
    """A finite real number from a decoder (JSON, CBOR): a finite float, or an int a float can hold
    (not a bool). A bignum such as 2**1100 is not one: `math.isfinite` raises OverflowError on it."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    return abs(v) <= sys.float_info.max if isinstance(v, int) else math.isfinite(v)


def not_a_file(p: Path, what: str) -> str:
    """Why `p` (not `is_file()`) cannot be read as a `what` file."""
    return f"is a directory, not a {what} file" if p.is_dir() else f"{what} file not found" if not p.exists() else "not a regular file"


def same_file(a: str | Path, b: str | Path) -> bool:
    """Whether `a` and `b` name one file (symlinks, hard links, `..`), without opening either."""
    try:
        return os.path.samefile(a, b)
    except OSError:  # one does not exist (yet): compare where the paths lead
        try:
            return Path(a).resolve() == Path(b).resolve()
        except (OSError, RuntimeError):  # a symlink loop
            return False


def check_output(path: str | None, option: str, inputs: Iterable[str | Path] = ()) -> None:
    """Fail fast (before a long bench) if `path` cannot be an output file: its directory must
    exist and take a new file (tried), an existing file must open for writing, and it must not be
    a directory itself, nor one of the command's `inputs` (files it reads: `--json` naming the
    run log or a photo would write over it). None: nothing to check."""
    if path is None:
        return
    if not path:  # `--json ""` was taken for "not given" and nothing was written
        raise UserError(f"{option}: empty file name")
    p = Path(path)
    for q in inputs:
        if Path(q).exists() and same_file(p, q):
            raise UserError(f"{option} {path}: is {q}, an input of this command; name another file")
    parent = p.parent
    if p.is_dir():
        raise UserError(f"{option} {path}: is a directory, not a file")
    if not parent.is_dir():
        # the nearest part of the path that exists says why: a file where a directory should be
        there = next((a for a in (parent, *parent.parents) if a.exists()), None)
        if there is not None and not there.is_dir():
            raise UserError(f"{option} {path}: {there} is a file, not a directory")
        raise UserError(f"{option} {path}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UserError(f"{option} {path}: directory {parent} is not writable")
    # os.access says yes to root everywhere, and /proc, /sys or a read-only mount refuse only the
    # write itself: so try one (a file of our own, removed at once; an existing file is opened for
    # appending, which leaves it as it was). A device or a pipe (/dev/stdout, a FIFO that blocks
    # until its reader comes) is left to the write itself.
    try:
        if p.is_file():
            with open(p, "a"):
                pass
        elif not p.exists():
            with tempfile.TemporaryFile(dir=parent):
                pass
    except OSError as e:
        raise UserError(f"{option} {path}: cannot write there ({e.strerror or e})") from None


def write_output(path: str, text: str, option: str) -> None:
    """Write `text` to `path`; an OS error is a UserError naming the option and the reason."""
    try:
        with open(path, "w") as f:
            f.write(text)
    except OSError as e:
        raise UserError(f"cannot write {option} {path!r}: {e.strerror or e}") from None
