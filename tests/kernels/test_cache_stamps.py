"""Compiled kernels are stamped with their sources' content (kernels/jit.py's KernelCacheLocator,
kernels/cachedir.py's source_digest): an upgrade that writes the same files again (new mtimes)
keeps every cached kernel; a changed file recompiles its subpackage, and only that one.

Each step is a fresh process importing a copy of kernels/ and calling one small reader kernel
(vdb/leaves.py's popcount). numba < 0.68 stamps entries with the file's (mtime, size); 0.68 hashes
the content itself. The processes here put the old stamp on numba's own locators, so the test
holds whichever numba is installed: only a locator of our own that stamps content passes it.
"""

import json
import os
import shutil
import subprocess
import sys

from conftest import COUNT_COMPILES, ROOT

sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
from bench_cold_start import touch_all  # noqa: E402  (a reinstall: what the bench measures too)

CHILD = r"""
import json, os, sys
sys.path.insert(0, sys.argv[1])
from numba.core import caching

def mtime_stamp(self):  # numba < 0.68's stamp, for every locator that takes numba's own
    st = os.stat(self._py_file)
    return st.st_mtime, st.st_size

caching._SourceFileBackedLocatorMixin.get_source_stamp = mtime_stamp
%(count)simport numpy as np
from kernels.vdb import leaves

assert os.path.realpath(leaves.__file__).startswith(os.path.realpath(sys.argv[1]))
masks = np.zeros((3, 64), np.uint8)
masks[1] = 255
assert leaves.popcount_rows(masks).tolist() == [0, 512, 0]
print(json.dumps(compiled))
""" % {"count": COUNT_COMPILES}


def _compiled(src, cache):
    env = dict(os.environ, GAUSSVDB_CACHE_DIR=str(cache))
    env.pop("NUMBA_CACHE_DIR", None)
    out = subprocess.run([sys.executable, "-c", CHILD, str(src)], env=env, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_upgrade_with_the_same_files_keeps_compiled_kernels(tmp_path):
    src, cache = tmp_path / "src", tmp_path / "cache"
    kernels = src / "kernels"
    shutil.copytree(os.path.join(ROOT, "kernels"), kernels,
                    ignore=shutil.ignore_patterns("__pycache__"))
    assert "_popcount" in _compiled(src, cache)  # cold: compiles
    assert _compiled(src, cache) == []  # warm

    touch_all(kernels, 1000.0)  # a reinstall: the same files, new mtimes
    assert _compiled(src, cache) == []
    shutil.rmtree(kernels)  # a fresh copy (new inodes, new mtimes)
    shutil.copytree(os.path.join(ROOT, "kernels"), kernels,
                    ignore=shutil.ignore_patterns("__pycache__"))
    touch_all(kernels, 2000.0)
    assert _compiled(src, cache) == []

    with open(kernels / "lod" / "fit.py", "a") as fh:  # another subpackage changed: kept
        fh.write("\n# another version\n")
    assert _compiled(src, cache) == []

    with open(kernels / "vdb" / "codec.py", "a") as fh:  # a file of the kernel's subpackage
        fh.write("\n# another version\n")
    assert "_popcount" in _compiled(src, cache)
    assert _compiled(src, cache) == []
