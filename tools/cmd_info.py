"""`gaussvdb info FILE.vdb [--json]`: grids, classes, counts, bounding boxes, transforms."""

import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # the sibling tools modules

import cli_errors  # noqa: E402


def main(argv):
    ap = cli_errors.ArgumentParser(prog="gaussvdb info", description="Describe the grids of a .vdb "
                                   "file (topology only: no values are decompressed).")
    ap.add_argument("file", help=".vdb file")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)
    from kernels.vdb.info import describe, format_text

    d = describe(args.file)  # an unreadable file: VDBFormatError, one line from cli_errors.run
    print(json.dumps(d, indent=1) if args.json else format_text(d))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
    sys.exit(cli_errors.run("gaussvdb info", main, sys.argv[1:]))
