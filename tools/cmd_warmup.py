"""`gaussvdb warmup [--jobs a,b] [--cache-dir DIR] [--for render|convert|both] [--force]`:
compile the numba kernels now (kernels/warmup.py's jobs), so later commands load them.

numba's cache entries load only under the module names they were compiled under
(kernels/cachedir.py). `./gaussvdb render` (and `demo`) run the extension in the bpy module as
`bl_ext.user_default.gaussvdb` (tools/blender_session.py), `./gaussvdb convert` imports `kernels`
directly: `--for` says which to warm (default render). The cache root is the one those commands
use: `--cache-dir`, else GAUSSVDB_CACHE_DIR, else the user's cache folder.
"""

import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # the sibling tools modules

import cli_errors  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def packages(which: str, names) -> list:
    """(label, package the kernels are imported under, jobs) of each identity to warm."""
    from blender_session import MODULE

    out = []
    if which in ("render", "both"):
        out.append(("render", MODULE, names))
    if which in ("convert", "both"):
        out.append(("convert", "", names))
    return out


def main(argv):
    ap = cli_errors.ArgumentParser(prog="gaussvdb warmup", description="Compile the GaussVDB "
                                   "kernels into their cache now (one line per job, its seconds).")
    ap.add_argument("--jobs", default="", help="comma-separated jobs (default all): "
                    "reader, lod:<preset>, error, render:<mode>")
    ap.add_argument("--cache-dir", default="", help="the compiled kernels' cache root (default "
                    "GAUSSVDB_CACHE_DIR, else the user's cache folder)")
    ap.add_argument("--for", dest="which", choices=("render", "convert", "both"), default="render",
                    help="the commands whose kernels to warm: render (and demo, blender -b with "
                         "this checkout), convert, or both (default render)")
    ap.add_argument("--force", action="store_true", help="run jobs already marked compiled too")
    ap.add_argument("--processes", type=cli_errors.threads, default=0, help="jobs compiled at "
                    "once, each in a process of its own (0: one per core, at most 4)")
    args = ap.parse_args(argv)
    sys.path.insert(0, ROOT)
    from kernels import cachedir, warmup

    try:
        names = warmup.check_names([n.strip() for n in args.jobs.split(",") if n.strip()] or None)
    except ValueError as err:
        raise cli_errors.UsageError(f"--jobs: {err}") from None
    root = os.path.abspath(args.cache_dir or os.environ.get("GAUSSVDB_CACHE_DIR")
                           or cachedir.user_cache_root())
    # every command started from here finds the same root (blender_session sets the same default)
    os.environ["GAUSSVDB_CACHE_DIR"] = root
    from kernels.warmup_boot import import_as

    total = 0.0
    for label, package, jobs in packages(args.which, names):
        mod = import_as(package, ROOT)
        mod.cachedir.set_cache_root(root)
        todo = jobs if args.force else mod.missing(jobs)
        print(f"gaussvdb warmup: {label} kernels ({package or 'kernels'}) in {mod.identity_dir()}: "
              f"{len(todo)} of {len(jobs)} jobs to run", flush=True)
        t0 = time.perf_counter()

        def line(name, seconds, todo=todo, count=[0]):
            count[0] += 1
            print(f"  [{count[0]}/{len(todo)}] {name:<18} {seconds:7.1f} s", flush=True)
        try:
            mod.warm(todo, mod.status_path(), on_done=line, force=args.force,
                     processes=args.processes or mod.default_processes())
        except mod.WarmupError as err:
            raise cli_errors.InputError(str(err)) from None
        spent = time.perf_counter() - t0
        total += spent
        print(f"  {label}: {spent:.1f} s; cache {mod.cache_size() / 1e6:.1f} MB", flush=True)
    print(f"gaussvdb warmup: done in {total:.1f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.path.insert(0, ROOT)
    sys.exit(cli_errors.run("gaussvdb warmup", main, sys.argv[1:]))
