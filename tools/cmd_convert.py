"""`./gaussvdb convert FILE.vdb [--grid G] [--vector-magnitude] --lod PRESET [--weights paper|field]
[--tolerance T [--max-error E]] [--out F.npz] [--json]`, or a sequence: `./gaussvdb convert
'DIR/name_####.vdb' [--frames A-B] --lod PRESET --cache-dir DIR [--json]`

Reads one grid (default: the first scalar grid with active voxels; a Mantaflow cache: density),
builds its Gaussians through kernels.pipeline (the add-on's import runs the same conversion),
measures the field error and prints one JSON object (indented; one line with --json). Times:
each phase (PHASES: start-up of the process, the file's topology, read, preparation, kernels'
loading, LOD build, field error, compact encoding, --out write) and seconds_total, the whole
command up to printing (seconds_other: what no phase covers); seconds_convert is build + error +
encoding (the conversion after reading) and mvoxels_per_second the active voxels over read +
seconds_convert. With
`--lod adaptive` the object also says whether the tolerance was met (and a warning on stderr says
what was met when it was not); on a terminal, stderr gets a line per round as it ends. --out
writes the compact encoding (kernels.lod.encode_compact) as an .npz that kernels.lod.decode_compact
reads back. A refusal is one line on stderr (tools/cli_errors.py).

A sequence is converted frame by frame into the on-disk cache the add-on reads (Render >
Sequences > Disk Cache with this folder): one file per frame, grid and LOD, so a render node
given the folder converts nothing. One JSON object: per frame the seconds, Gaussians, cache and
.vdb bytes; an unreadable frame is an error naming it, the others are still converted.
"""
from __future__ import annotations

import json
import os
import sys
import time
import warnings

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # the sibling tools modules

import cli_errors  # noqa: E402
import cluster  # noqa: E402

T_START = time.perf_counter()  # when the command's own code began (see started_seconds_ago)


def started_seconds_ago() -> float:
    """Seconds since this process started (Linux: its start time; else since T_START), so that
    seconds_total covers the interpreter's start-up too."""
    try:
        with open("/proc/self/stat") as f:
            ticks = int(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as f:
            up = float(f.read().split()[0])
        return max(up - ticks / os.sysconf("SC_CLK_TCK"), time.perf_counter() - T_START)
    except (OSError, ValueError, IndexError):
        return time.perf_counter() - T_START


# The command's phases in order; with seconds_other they sum to seconds_total.
PHASES = ("seconds_start", "seconds_topology", "seconds_read", "seconds_prepare", "seconds_compile",
          "seconds_build", "seconds_error", "seconds_encode", "seconds_write")


def _progress(fraction, text):
    """On a terminal, the steps a long conversion reports (the adaptive preset's rounds)."""
    if ", round " in text:
        print(f"gaussvdb convert: {text}", file=sys.stderr, flush=True)


def convert(path, grid, options, out=None) -> dict:
    """One grid (``grid``, or the default one) of ``path`` at the one LOD of the ConvertOptions
    ``options``: the JSON figures."""
    import cli_grids
    import numpy as np

    from kernels import pipeline
    from kernels.lod import encode_compact, encoded_nbytes, paper_model_bytes

    (lod,), color_grid, error = options.lods, options.color_grid, options.compute_error
    t_start = started_seconds_ago()
    t0 = time.perf_counter()
    name = cli_grids.choose_grid(path, grid, options.vector_magnitude)
    if color_grid:
        cli_grids.check_color_grid(path, color_grid, options.vector_magnitude)
    t_topology = time.perf_counter() - t0
    t0 = time.perf_counter()
    with warnings.catch_warnings():  # NaN/Inf voxels: said in one line below
        warnings.filterwarnings("ignore", message=".*non-finite", category=RuntimeWarning)
        try:
            cg = pipeline.convert_file(path, options=options.replace(grids=(name,)),
                                       progress=_progress if sys.stderr.isatty() else None)[0]
        except pipeline.ConversionError as err:
            raise cli_errors.InputError(str(err)) from err
    t_pipeline = time.perf_counter() - t0
    if cg.nonfinite_voxels:
        print(f"gaussvdb convert: warning: {cg.nonfinite_voxels:,} NaN/Inf voxels of grid {cg.name!r} "
              "made inactive", file=sys.stderr)
    cl = cg.lods[0]
    gs = cl.gset
    t0 = time.perf_counter()
    enc = encode_compact(gs)
    nbytes = encoded_nbytes(enc)
    t_encode = time.perf_counter() - t0
    # phases: reading the file, the rest of the pipeline's preparation (sanitizing, the grid's
    # figures), loading the kernels, building the LOD, its field error, the compact encoding
    phases = dict(seconds_start=t_start, seconds_topology=t_topology, seconds_read=cg.seconds_read,
                  seconds_prepare=max(0.0, t_pipeline - cg.seconds_read - cg.seconds_compile
                                      - cl.seconds - cl.seconds_error),
                  seconds_compile=cg.seconds_compile, seconds_build=cl.seconds,
                  seconds_error=cl.seconds_error, seconds_encode=t_encode)
    seconds_convert = cl.seconds + cl.seconds_error + t_encode
    res = {
        "file": os.path.basename(path), "grid": cg.name, "class": cg.grid_class, "lod": lod,
        "weights": options.weights, "active_voxels": cg.active_voxels, "leaves": cg.leaves,
        "tiles": cg.tiles, "gaussians": gs.count,
        "spheres": gs.n_spheres, "ellipsoids": gs.n_ellipsoids, "bytes": nbytes,
        "bytes_per_gaussian": nbytes / gs.count if gs.count else 0.0,
        "paper_model_bytes": paper_model_bytes(gs), **phases,
        "seconds_convert": seconds_convert,
        "mvoxels_per_second": cg.active_voxels / max(cg.seconds_read + seconds_convert, 1e-9) / 1e6,
        "kept_voxels": int(gs.voxels.astype(np.int64).sum()),
        "level_set_band": bool(gs.params.get("level_set_band", False)),
        "nonfinite_voxels": cg.nonfinite_voxels,
    }
    if lod == "merged":  # runs merged, and (field weights) the merges the field check undid
        res.update(merged=int(gs.params.get("merged", 0)),
                   merges_undone=int(gs.params.get("merges_undone", 0)))
    if lod == "adaptive":
        p = gs.params
        res.update(tolerance=p["tolerance"], max_error=p["max_error"] or None,
                   tolerance_met=p["tolerance_met"], achieved_nrmse=p["achieved_nrmse"],
                   achieved_max_abs=p["achieved_max_abs"], rounds=p["rounds"])
        if not p["tolerance_met"]:
            bound = f"NRMSE {p['tolerance']:g}" + (f", max {p['max_error']:g}" if p["max_error"] else "")
            print(f"gaussvdb convert: warning: tolerance ({bound}) not met on grid {cg.name!r}: "
                  f"reached NRMSE {p['achieved_nrmse']:.4g}, max {p['achieved_max_abs']:.4g} "
                  "with a Gaussian per voxel where the error is", file=sys.stderr)
    if error:
        e = cl.error
        if not e:
            raise MemoryError  # the field error could not be measured
        res.update(field_rmse=e["rmse"], field_nrmse=e["nrmse"], field_max_abs=e["max_abs"],
                   field_nrmse_denominator=e["nrmse_denominator"], field_reference=e["reference"],
                   field_k_sigma=e["k_sigma"])
        if "surface_iou" in e:
            res.update(surface_iou=e["surface_iou"], surface_mismatch=e["surface_mismatch"])
    if color_grid:  # the colour grid's value at every Gaussian (timed within seconds_prepare)
        cv = gs.color_values.astype(np.float64)
        fin = np.isfinite(cv)
        res.update(color_grid=color_grid, seconds_color=cl.seconds_color,
                   color_min=float(cv[fin].min()) if fin.any() else None,
                   color_max=float(cv[fin].max()) if fin.any() else None)
        enc = dict(enc, color_values=gs.color_values)
    t0 = time.perf_counter()
    if out:
        np.savez(out, **enc)
        res["out"] = out
    res["seconds_write"] = time.perf_counter() - t0
    return res


def finish_timing(res):
    """seconds_total (from the process's start to now, just before printing) and seconds_other:
    what no phase covers (the figures' assembly, argument parsing)."""
    res["seconds_total"] = started_seconds_ago()
    res["seconds_other"] = res["seconds_total"] - sum(res[k] for k in PHASES)
    return res


def convert_sequence(pattern, frames, grid, lod, cache_dir, options) -> dict:
    """Every frame of a sequence into the add-on's disk cache (kernels.sequence.write_frame),
    each frame converted as the add-on converts one (kernels.pipeline.convert_frame) with the
    object settings of the ConvertOptions ``options``."""
    import cli_grids

    from kernels import pipeline
    from kernels import sequence as seq

    pat, present, name = cli_grids.sequence_frames(pattern, frames, grid, options.vector_magnitude)
    items, errors = [], []
    t_all = time.perf_counter()
    for n in present:
        path = pat.path(n)
        item = {"frame": n, "file": os.path.basename(path), "vdb_bytes": os.path.getsize(path)}
        t0 = time.perf_counter()
        with warnings.catch_warnings():  # NaN/Inf voxels made inactive, as the add-on does
            warnings.filterwarnings("ignore", message=".*non-finite", category=RuntimeWarning)
            cg, why = pipeline.convert_frame(path, name, lod, options)
        if why:
            msg = f"frame {n}: {why}"
            errors.append(msg)
            item["error"] = msg
            print(f"gaussvdb convert: error: {msg}", file=sys.stderr)
            items.append(item)
            continue
        gs = cg.lods[0].gset if cg is not None else None
        values = (cg.values or None) if cg is not None else None
        out = os.path.join(cache_dir, seq.cache_name(path, name, lod, options))
        item.update(seconds=time.perf_counter() - t0, gaussians=gs.count if gs is not None else 0,
                    cache_bytes=seq.write_frame(out, gs, values, path, name, lod),
                    cache_file=os.path.basename(out))
        items.append(item)
    done = [i for i in items if "cache_bytes" in i]
    return {"pattern": pat.path(0).replace(pat.name(0), pat.text), "grid": name, "lod": lod,
            "weights": options.weights, "cache_dir": os.path.abspath(cache_dir), "frames": items,
            "seconds_total": time.perf_counter() - t_all,
            "cache_bytes": sum(i["cache_bytes"] for i in done),
            "vdb_bytes": sum(i["vdb_bytes"] for i in done), "errors": errors}


def main(argv: list[str]) -> int:
    from kernels import lod_names
    from kernels.convert_options import ConvertOptions
    from kernels.lod import DEFAULTS, PRESETS, WEIGHTS

    ap = cli_errors.ArgumentParser(prog="gaussvdb convert", description=__doc__.split("\n\n")[1])
    ap.add_argument("file", help="a .vdb file, or a sequence: 'DIR/name_####.vdb'")
    ap.add_argument("--frames", help="frames of a sequence: 35-50 (default: every frame found)")
    ap.add_argument("--cache-dir", help="a sequence: the disk-cache folder to write")
    ap.add_argument("--grid", help="grid name (default: the first scalar grid with active voxels; "
                         "a Mantaflow cache: density)")
    ap.add_argument("--vector-magnitude", action="store_true",
                    help="vec3 grids (velocity) count as their magnitude, as in the importer")
    ap.add_argument("--lod", choices=PRESETS, default=lod_names.DEFAULT)
    ap.add_argument("--weights", choices=WEIGHTS, default=WEIGHTS[0])
    ap.add_argument("--out", help="write the compact encoding to this .npz")
    ap.add_argument("--color-grid", metavar="NAME",
                    help="also the value of this other grid at every Gaussian (stored in --out "
                         "as color_values)")
    ap.add_argument("--json", action="store_true", help="one line of JSON")
    ap.add_argument("--no-band", action="store_true",
                    help="level sets: keep the whole narrow band, not only the zero-crossing shell")
    ap.add_argument("--no-error", action="store_true", help="skip the field error")
    ap.add_argument("--threads", type=cli_errors.threads, help="numba threads (0: all)")
    cluster.add_arguments(ap)
    for k, v in DEFAULTS.items():
        parse = (cli_errors.nonnegative if k in ("tolerance", "max_error") else
                 cli_errors.on_off if isinstance(v, bool) else type(v))
        ap.add_argument("--" + k.replace("_", "-"), default=None, help=f"threshold (default {v})",
                        type=parse)
    a = ap.parse_args(argv)
    if a.threads and not cluster.wanted(a):
        import numba
        numba.set_num_threads(a.threads)
    th = {k: getattr(a, k) for k in DEFAULTS if getattr(a, k) is not None}
    opts = ConvertOptions(lods=(a.lod,), weights=a.weights, level_set_band=not a.no_band,
                          vector_magnitude=a.vector_magnitude, compute_error=not a.no_error,
                          thresholds=th, color_grid=a.color_grid, value_figures=False)
    if a.frames or a.cache_dir or "#" in os.path.basename(a.file):
        from kernels import sequence as seq

        if not a.cache_dir:
            raise cli_errors.UsageError("a sequence converts into a disk cache: give --cache-dir DIR",
                                        "gaussvdb convert")
        if a.color_grid:
            raise cli_errors.UsageError("--color-grid converts one file, not a sequence",
                                        "gaussvdb convert")
        if th or a.out:  # the cache must hold what the add-on would convert
            raise cli_errors.UsageError("--cache-dir takes the preset's own thresholds and no --out",
                                        "gaussvdb convert")
        try:
            frames = seq.parse_frames(a.frames) if a.frames else None
        except ValueError as err:
            raise cli_errors.UsageError(f"--frames: {err}", "gaussvdb convert") from None
        if cluster.wanted(a):  # one task per frame on a Dask cluster (tools/cluster.py)
            res = cluster.convert_sequence(a.file, frames, a.grid, a.lod, a.cache_dir, opts,
                                           workers=a.workers, scheduler=a.scheduler,
                                           cores=a.threads or 0)
        else:
            res = convert_sequence(a.file, frames, a.grid, a.lod, a.cache_dir, opts)
        print(json.dumps(res) if a.json else json.dumps(res, indent=2))
        return 1 if res["errors"] else 0
    if cluster.wanted(a):
        raise cli_errors.UsageError("--workers/--scheduler convert a sequence ('DIR/name_####.vdb' "
                                    "--cache-dir DIR)", "gaussvdb convert")
    res = convert(a.file, a.grid, opts, out=a.out)
    res = finish_timing(res)
    print(json.dumps(res) if a.json else json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    sys.exit(cli_errors.run("gaussvdb convert", main, sys.argv[1:]))
