"""The saved cases (gpu_cases.py) packed for the GPU machine, whose calls carry 64 MiB each
(gpu_real.CARRY_LIMIT, the working tree and the wheels included): tables that several cases hold
(splat on a level set draws the voxels as reference does; the Gaussian modes of one LOD share
their tile inputs and often their records; every view of a case shares its tables) stored once in
a folder's ``pool.tables``, and the cases, in units that share no table with another unit,
shared out among as few folders as keep each call under the limit with gpu_real.MARGIN to
spare. Numpy only.

    python benchmarks/gpu_pack.py CASES DEST [--record FILE]   # DEST/1, DEST/2, ...: a call each

Each folder holds its cases (``CASE.npz``: case.json and the small arrays, ``pooled`` naming the
pool's key of each moved one), their ``.fallback.json`` files and ``pool.tables`` (an npz under
another name, so a run's glob of ``*.npz`` does not take it for a case: each table's bytes as
planes, its dtype and shape in ``index.json``); gl_backend.Case reads
them. Prints one JSON line per folder (its cases, sources, MiB) and writes DEST/groups.json;
--record: that too, with each folder's case names and each saved case's bytes (what
tests/e2e/test_gpu_payload.py checks: benchmarks/gpu_payload.json)."""
from __future__ import annotations

import argparse
import glob
import hashlib
import io
import json
import os
import shutil
import sys
import zlib

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
POOL = "pool.tables"
POOL_MIN = 1 << 16  # arrays of at least these bytes go to the pool
JOIN_MIN = 1 << 20  # cases sharing a table of at least these bytes (compressed) go together


def _read(path):
    """(case.json dict, {key: array}) of a saved case."""
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    return json.loads(str(arrays.pop("case.json"))), arrays


def _key(a):
    h = hashlib.sha1(f"{a.dtype.str}{a.shape}".encode())
    h.update(np.ascontiguousarray(a).data)
    return h.hexdigest()[:20]


def _shuffled(a):
    """An array's bytes as planes (every element's first byte, then every second, ...): float
    tables compress a fifth better so (gl_backend.pool reads them back)."""
    a = np.ascontiguousarray(a)
    return np.ascontiguousarray(a.view(np.uint8).reshape(-1, a.dtype.itemsize).T)


def _deflated(a):
    """An array's bytes in an npz (deflate, as np.savez_compressed writes it)."""
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.ascontiguousarray(a))
    return len(zlib.compress(buf.getvalue(), 6))


def plan(cases):
    """[(case files, {pool key: deflated bytes}, bytes of the rest)]: the cases in units that
    share no table of JOIN_MIN bytes with another unit (one source's reference and splat cases on
    its voxels, a LOD's Gaussian modes sharing their tile inputs, ...)."""
    each, sized = [], {}
    for path in sorted(glob.glob(os.path.join(cases, "*.npz"))) + sorted(
            glob.glob(os.path.join(cases, "*.fallback.json"))):
        pool, rest = {}, 0
        if path.endswith(".json"):
            rest = os.path.getsize(path)
        else:
            for k, a in _read(path)[1].items():
                if a.nbytes >= POOL_MIN and not k.endswith(".cpu"):
                    key = _key(a)
                    if key not in sized:
                        sized[key] = _deflated(_shuffled(a))
                    pool[key] = sized[key]
                else:
                    rest += _deflated(a)
        each.append((path, pool, rest))
    parent = list(range(len(each)))

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    owner = {}
    for i, (_, pool, _) in enumerate(each):
        for key, size in pool.items():
            if size >= JOIN_MIN:  # (a smaller one is stored in each folder that needs it)
                parent[root(i)] = root(owner.setdefault(key, i))
    units = {}
    for i, (path, pool, rest) in enumerate(each):
        files, keys, r = units.setdefault(root(i), ([], {}, [0]))
        files.append(path)
        keys.update(pool)
        r[0] += rest
    return [(files, keys, r[0]) for files, keys, r in units.values()]


def groups(sizes, room):
    """Units (index: bytes) shared out, largest first, into the first folder with room."""
    bins = []
    for unit, size in sorted(sizes.items(), key=lambda kv: -kv[1]):
        for b in bins:
            if b[0] + size <= room:
                b[0] += size
                b[1].append(unit)
                break
        else:
            bins.append([size, [unit]])
    return [sorted(b[1]) for b in bins]


def write(files, dest):
    """The cases in files written to dest with their big arrays in one pool."""
    os.makedirs(dest, exist_ok=True)
    pool = {}
    for path in files:
        if path.endswith(".json"):
            shutil.copy(path, dest)
            continue
        info, arrays = _read(path)
        keep, pooled = {}, {}
        for k, a in arrays.items():
            if a.nbytes >= POOL_MIN and not k.endswith(".cpu"):
                pooled[k] = key = _key(a)
                pool[key] = a
            else:
                keep[k] = a
        info["pooled"] = pooled
        np.savez_compressed(os.path.join(dest, os.path.basename(path)), **keep,
                            **{"case.json": np.array(json.dumps(info))})
    index = {k: [a.dtype.str, list(a.shape)] for k, a in pool.items()}
    with open(os.path.join(dest, POOL), "wb") as f:
        np.savez_compressed(f, **{k: _shuffled(a) for k, a in pool.items()},
                            **{"index.json": np.array(json.dumps(index))})


def main(argv=None):
    import gpu_real

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cases")
    ap.add_argument("dest")
    ap.add_argument("--record", default=None)
    a = ap.parse_args(argv)
    p = plan(a.cases)
    sizes = {i: sum(pool.values()) + rest for i, (_, pool, rest) in enumerate(p)}
    fixed = gpu_real.tree_bytes() + sum(gpu_real.folder_bytes(os.path.join(gpu_real.ROOT, n)) for n in (".whl", ".gl"))
    room = gpu_real.CARRY_LIMIT - gpu_real.MARGIN - fixed
    room -= room // 32  # (the sizes are each unit's alone: a folder's own compression differs a little)
    if os.path.isdir(a.dest):
        shutil.rmtree(a.dest)
    out = []
    for i, units in enumerate(groups(sizes, room), 1):
        dest = os.path.join(a.dest, str(i))
        files = sorted(f for u in units for f in p[u][0])
        write(files, dest)
        mib = gpu_real.folder_bytes(dest) / 2 ** 20
        out.append({"folder": str(i), "sources": sorted({os.path.basename(f).split(".", 1)[0] for f in files}),
                    "cases": len(files), "MiB": round(mib, 2), "call MiB": round(mib + fixed / 2 ** 20, 2)})
        print(json.dumps(out[-1]), flush=True)
        out[-1].update(bytes=gpu_real.folder_bytes(dest), names=sorted(os.listdir(dest)))
        for u in units:
            if sizes[u] > room:
                print(f"{len(p[u][0])} cases sharing {sizes[u] / 2 ** 20:.1f} MiB of tables, past one call's "
                      f"room ({room / 2 ** 20:.1f} MiB)", flush=True)
    fixed_parts = {n: gpu_real.folder_bytes(os.path.join(gpu_real.ROOT, n)) for n in (".whl", ".gl")}
    res = {"room_MiB": round(room / 2 ** 20, 2), "fixed": dict(fixed_parts, **{"working tree": gpu_real.tree_bytes()}),
           "groups": out}
    with open(os.path.join(a.dest, "groups.json"), "w") as f:
        json.dump(res, f, indent=1)
    if a.record:
        saved = {os.path.basename(f): os.path.getsize(f) for f in sorted(glob.glob(os.path.join(a.cases, "*.npz")))}
        with open(a.record, "w") as f:
            json.dump(dict(res, saved=saved), f, indent=1)
            f.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
