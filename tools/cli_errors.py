"""How every `./gaussvdb` command refuses: one line `gaussvdb <cmd>: <message>` on stderr, exit
status 2 for bad arguments and 1 for input that cannot be used, never a traceback. `--debug`
anywhere on the command line (or GAUSSVDB_DEBUG=1) lets the exception through with its traceback.

    ap = cli_errors.ArgumentParser(prog="gaussvdb render")    # bad options: UsageError (exit 2)
    ap.add_argument("--size", type=cli_errors.size, ...)      # WxH, both > 0
    raise cli_errors.InputError(f"no scalar grid in {path}")  # a file that cannot be used (exit 1)
    sys.exit(cli_errors.run("gaussvdb render", main, sys.argv[1:]))
"""
from __future__ import annotations

import argparse
import math
import os
import sys


class UsageError(Exception):
    """A bad option or argument: exit status 2. ``prog`` (if set) starts the line."""

    exit_code = 2

    def __init__(self, message, prog=None):
        super().__init__(message)
        self.prog = prog


class InputError(Exception):
    """A file (or folder) that cannot be used: exit status 1."""

    exit_code = 1
    prog = None


class ArgumentParser(argparse.ArgumentParser):
    """argparse whose errors are one line (no usage block), raised so `run` prints them."""

    def error(self, message):
        raise UsageError(message, self.prog)


# -- option types (argparse names the option in front of the message) ------------------------------
def size(text: str) -> tuple:
    """'640x480' -> (640, 480); both sides whole numbers > 0."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must look like 640x480, not {text!r}") from None
    if w <= 0 or h <= 0:
        raise argparse.ArgumentTypeError(f"width and height must be > 0, not {text!r}")
    return w, h


def clip_plane(text: str) -> tuple:
    """'px,py,pz,nx,ny,nz' -> a world point and a non-zero normal (the side it points to stays)."""
    v = _floats(text, 6, "px,py,pz,nx,ny,nz")
    if not any(v[3:]):
        raise argparse.ArgumentTypeError(f"the normal (last three numbers) must not be zero, not {text!r}")
    return v[:3], v[3:]


def direction(text: str) -> tuple:
    """'dx,dy,dz' -> a non-zero world direction."""
    v = _floats(text, 3, "dx,dy,dz")
    if not any(v):
        raise argparse.ArgumentTypeError(f"must not be zero, not {text!r}")
    return v


def clip_box(text: str) -> tuple:
    """'x0,y0,z0,x1,y1,z1' -> the world box's min and max corners (min < max on every axis)."""
    v = _floats(text, 6, "x0,y0,z0,x1,y1,z1")
    if not all(a < b for a, b in zip(v[:3], v[3:])):
        raise argparse.ArgumentTypeError(f"needs x0 < x1, y0 < y1 and z0 < z1, not {text!r}")
    return v[:3], v[3:]


def value_range(text: str) -> tuple:
    """'min,max' -> a transfer function's value range: two finite numbers, min < max."""
    lo, hi = _floats(text, 2, "MIN,MAX")
    if not lo < hi:
        raise argparse.ArgumentTypeError(f"needs MIN < MAX, not {text!r}")
    return lo, hi


def _floats(text, n, shape):
    try:
        v = tuple(float(x) for x in text.split(","))
    except ValueError:
        v = ()
    if len(v) != n or not all(math.isfinite(x) for x in v):
        raise argparse.ArgumentTypeError(f"must be {n} finite numbers {shape}, not {text!r}")
    return v


def threads(text: str) -> int:
    """A thread count: 0 (all cores) up to the cores numba may use."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a whole number, not {text!r}") from None
    most = max_threads()
    if not 0 <= n <= most:
        raise argparse.ArgumentTypeError(f"must be 0 (all) to {most} on this machine, not {n}")
    return n


def max_threads() -> int:
    import numba

    return int(numba.config.NUMBA_NUM_THREADS)


def on_off(text: str) -> bool:
    """A switch: on/off, true/false, yes/no or 1/0."""
    t = text.strip().lower()
    if t in ("on", "true", "yes", "1"):
        return True
    if t in ("off", "false", "no", "0"):
        return False
    raise argparse.ArgumentTypeError(f"must be on or off, not {text!r}")


def nonnegative(text: str) -> float:
    """A finite number >= 0 (a density)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, not {text!r}") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"must be finite and >= 0, not {text!r}")
    return v


def positive_int(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a whole number, not {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, not {n}")
    return n


def positive_ints(text: str) -> list:
    """'1,4,16' -> [1, 4, 16], each >= 1."""
    return [positive_int(t) for t in text.split(",")]


def names(allowed):
    """Type of a comma-separated list whose items are all in ``allowed`` -> list."""
    def parse(text: str) -> list:
        items = [s for s in text.split(",") if s]
        bad = [s for s in items if s not in allowed]
        if bad or not items:
            raise argparse.ArgumentTypeError(f"{(bad or [text])[0]!r} is not one of {', '.join(allowed)}")
        return items
    return parse


def vdb_folder(folder: str) -> list:
    """The .vdb files of a data folder, sorted; InputError when there is none."""
    if not os.path.isdir(folder):
        raise InputError(f"no data folder {folder} (give one with --data DIR)")
    files = sorted(os.path.join(folder, f) for f in os.listdir(folder) if f.endswith(".vdb"))
    if not files:
        raise InputError(f"no .vdb files in {folder} (give a data folder with --data DIR)")
    return files


# -- the one wrapper ----------------------------------------------------------------------------------
def one_line(text) -> str:
    """Messages from Blender come as 'Error: X\\nError: X\\n': distinct lines, prefix dropped."""
    lines = []
    for line in str(text).splitlines():
        line = line.strip()
        line = line[len("Error: "):] if line.startswith("Error: ") else line
        if line and line not in lines:
            lines.append(line)
    return "; ".join(lines) or "failed"


def take_debug(argv: list) -> tuple:
    """(argv without --debug, debug on?)"""
    rest = [a for a in argv if a != "--debug"]
    debug = len(rest) != len(argv) or os.environ.get("GAUSSVDB_DEBUG", "") not in ("", "0")
    if debug:
        os.environ["GAUSSVDB_DEBUG"] = "1"  # sub-steps (and child processes) see it too
    return rest, debug


def debug_enabled() -> bool:
    return os.environ.get("GAUSSVDB_DEBUG", "") not in ("", "0")


def run(command: str, main, argv: list) -> int:
    """``main(argv)`` with every refusal turned into one line on stderr; returns the exit status."""
    argv, debug = take_debug(argv)
    if debug:
        return int(main(argv) or 0)
    try:
        return int(main(argv) or 0)
    except (UsageError, InputError) as err:
        code, prog, msg = err.exit_code, err.prog or command, str(err)
    except KeyboardInterrupt:
        code, prog, msg = 130, command, "interrupted"
    except MemoryError as err:  # the renderer's estimate says what it needs and what helps
        code, prog, msg = 1, command, str(err) or "out of memory"
    except SystemExit as err:  # argparse --help (0) passes; a message becomes the one line
        if err.code is None or isinstance(err.code, int):
            raise
        code, prog, msg = 1, command, str(err.code)
    except (ValueError, RuntimeError, OSError) as err:  # VDBFormatError is a ValueError
        code, prog, msg = 1, command, str(err) or type(err).__name__
    except Exception as err:  # noqa: BLE001 - a bug: still one line, the traceback on request
        code, prog = 1, command
        msg = f"internal error: {type(err).__name__}: {err}; run with --debug for the traceback"
    sys.stdout.flush()
    msg = one_line(msg)
    print(msg if msg.startswith(prog + ":") else f"{prog}: {msg}", file=sys.stderr, flush=True)
    return code
