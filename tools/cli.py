"""The `./gaussvdb` subcommands. Each lives in tools/cmd_<name>.py with a `main(argv) -> int`;
refusals become one line and an exit status here (tools/cli_errors.py)."""

import importlib
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

COMMANDS = {
    "demo": "import the bundled sample at every LOD, print the table, render it",
    "test": "run the whole test suite (pytest arguments pass through)",
    "compat": "the built zip in the oldest supported Blender (4.5): import, F12, save, reload",
    "build": "build the installable extension zips (one per platform)",
    "info": "list the grids of a .vdb file",
    "convert": "convert one grid to Gaussians at a LOD preset",
    "render": "render a .vdb through the GAUSSVDB engine to an image",
    "warmup": "compile the numba kernels now (farms, first runs): warmup [--jobs a,b] [--cache-dir DIR]",
    "bench": "benchmarks: bench [ingest|lod|render|stability|cold_start] ...",
}


def usage() -> str:
    lines = ["usage: ./gaussvdb COMMAND [ARGS]", "", "commands:"]
    lines += [f"  {name:<8} {text}" for name, text in COMMANDS.items()]
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    # The repository root is the extension's source root: `kernels` imports from here.
    sys.path.insert(0, ROOT)
    sys.path.insert(1, os.path.join(ROOT, "tools"))
    import cli_errors

    args, _ = cli_errors.take_debug(argv)
    if not args or args[0] in ("-h", "--help", "help"):
        print(usage())
        return 0
    name = args[0]
    if name not in COMMANDS:
        print(f"gaussvdb: unknown command {name!r} (commands: {', '.join(COMMANDS)}; "
              "./gaussvdb help)", file=sys.stderr)
        return 2
    rest = argv[argv.index(name) + 1:]  # --debug stays in: run() takes it out again
    if name == "test":  # pytest's own arguments (its --debug included) pass through untouched
        return int(importlib.import_module("cmd_test").main(rest) or 0)
    return cli_errors.run(f"gaussvdb {name}",
                          lambda a: importlib.import_module(f"cmd_{name}").main(a), rest)


if __name__ == "__main__":
    code = main(sys.argv[1:])
    if sys.argv[1:2] == ["convert"]:
        # its JSON times the whole command (seconds_total): skip tearing down the ~700 modules
        # numba loads, 0.3 s after the work is done and written
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)
