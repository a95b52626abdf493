"""The `./gaussvdb` subcommands. Each lives in tools/cmd_<name>.py with a `main(argv) -> int`."""

import importlib
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

COMMANDS = {
    "demo": "import the bundled sample at every LOD, print the table, render it",
    "test": "run the whole test suite (pytest arguments pass through)",
    "build": "build the installable extension zips (one per platform)",
    "info": "list the grids of a .vdb file",
    "convert": "convert one grid to Gaussians at a LOD preset",
    "render": "render a .vdb through the GAUSSVDB engine to an image",
    "bench": "benchmarks: bench [ingest|lod|render|stability] ...",
}


def usage() -> str:
    lines = ["usage: ./gaussvdb COMMAND [ARGS]", "", "commands:"]
    lines += [f"  {name:<8} {text}" for name, text in COMMANDS.items()]
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(usage())
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"gaussvdb: unknown command {name!r}\n\n{usage()}", file=sys.stderr)
        return 2
    # The repository root is the extension's source root: `kernels` imports from here.
    sys.path.insert(0, ROOT)
    sys.path.insert(1, os.path.join(ROOT, "tools"))
    module = importlib.import_module(f"cmd_{name}")
    return int(module.main(rest) or 0)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
