"""Longer fuzz of kernels.vdb: every outcome must be a read or a VDBFormatError, within a time bound.

    python benchmarks/fuzz_ingest.py [--n 5000] [--seed 0] [FILE.vdb ...]
A crash (segfault) ends the process: rerun with the printed seed and iteration to reproduce.
"""

import argparse
import glob
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))


def mutate(data, rng):
    b = bytearray(data)
    kind = rng.integers(0, 4)
    if kind == 0:
        return bytes(b[: int(rng.integers(0, len(b)))])
    for _ in range(int(rng.integers(1, 6))):
        pos = int(rng.integers(0, len(b)))
        if kind == 1:
            b[pos] ^= 1 << int(rng.integers(0, 8))
        elif kind == 2:
            b[pos:pos + 8] = rng.choice([b"\xff" * 8, b"\x7f" * 8, b"\x00" * 8])
        else:
            b[pos] = int(rng.integers(0, 256))
    return bytes(b)


def main(argv=None):
    from kernels.vdb import VDBFormatError, read_vdb
    ap = argparse.ArgumentParser(prog="fuzz_ingest")
    ap.add_argument("files", nargs="*")
    ap.add_argument("--n", type=int, default=5000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    files = args.files or sorted(f for f in glob.glob(os.path.join(
        os.path.dirname(__file__), "..", "..", "shared", "data", "*.vdb")) if os.path.getsize(f) < 2e6)
    sources = [open(f, "rb").read() for f in files]
    rng = np.random.default_rng(args.seed)
    counts = {"read": 0, "error": 0}
    worst = 0.0
    with tempfile.TemporaryDirectory() as d:
        p = os.path.join(d, "m.vdb")
        for i in range(args.n):
            data = mutate(sources[i % len(sources)], rng)
            open(p, "wb").write(data)
            t = time.perf_counter()
            try:
                read_vdb(p, allow_fallback=False, max_bytes=1 << 30)
                counts["read"] += 1
            except VDBFormatError:
                counts["error"] += 1
            worst = max(worst, time.perf_counter() - t)
            if i % 500 == 0:
                print(f"{i}/{args.n} {counts} slowest {worst:.3f}s", flush=True)
    print(f"done: {counts}, slowest case {worst:.3f} s; no other exception, no crash")


if __name__ == "__main__":
    main()
