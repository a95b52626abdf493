"""`gaussvdb info FILE.vdb [--json]`: grids, classes, counts, bounding boxes, transforms."""

import argparse
import json
import sys


def main(argv):
    ap = argparse.ArgumentParser(prog="gaussvdb info", description="Describe the grids of a .vdb file "
                                 "(topology only: no values are decompressed).")
    ap.add_argument("file", help=".vdb file")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)
    from kernels.vdb import VDBFormatError
    from kernels.vdb.info import describe, format_text
    try:
        d = describe(args.file)
    except VDBFormatError as e:
        print(f"gaussvdb info: {e}", file=sys.stderr)
        return 2
    print(json.dumps(d, indent=1) if args.json else format_text(d))
    return 0


if __name__ == "__main__":
    import os
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
    sys.exit(main(sys.argv[1:]))
