"""`./gaussvdb bench [NAME] [ARGS]`: run benchmarks/bench_NAME.py (default: the error-vs-time report)."""

import importlib.util
import os

from cli_errors import InputError, UsageError

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BENCH_DIR = os.path.join(ROOT, "benchmarks")


def available() -> list[str]:
    return sorted(f[len("bench_"):-3] for f in os.listdir(BENCH_DIR)
                  if f.startswith("bench_") and f.endswith(".py"))


def main(argv: list[str]) -> int:
    name = "report"
    if argv and not argv[0].startswith("-"):
        name, argv = argv[0], argv[1:]
    if name not in available():
        raise UsageError(f"no benchmark {name!r}; have: {', '.join(available())}")
    path = os.path.join(BENCH_DIR, f"bench_{name}.py")
    spec = importlib.util.spec_from_file_location(f"bench_{name}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    try:
        return int(module.main(argv) or 0)
    except InputError as err:  # the line names the benchmark
        err.prog = err.prog or ("gaussvdb bench" if name == "report" else f"gaussvdb bench {name}")
        raise
