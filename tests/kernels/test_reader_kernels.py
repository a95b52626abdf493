"""The reader compiles the decoders of the file's compression only: a file without blosc (a
Mantaflow cache: fog grids raw, the velocity zip) compiles no blosc frame decoder and no
byte-plane gather, and a blosc file compiles them (that both kinds read as the openvdb binding
does: test_vdb_reader.py, the warm-up fixtures and the transcoded variants). Each case runs in a
fresh process on an empty kernel cache (a kernel loaded from the cache brings its callees' code
without their dispatchers, so only a compile lists them)."""
import json
import os
import subprocess
import sys

import pytest
from conftest import ROOT, SAMPLE

from kernels import warmup
from kernels.vdb.info import uses_blosc

SCRIPT = """
import json, sys
from kernels import pipeline
from kernels.vdb import frames, leaves, tree
for path in sys.argv[1:]:
    pipeline.read_grids(path, vector_magnitude=True)
fns = dict(blosc_frame=frames.blosc_frame, lz4_block=frames.lz4_block, planes=leaves._planes,
           walk=tree._walk, decode=leaves._decode_rows, values=leaves._values)
print(json.dumps({k: len(f.signatures) for k, f in fns.items()}))
"""


def _compiled(tmp_path, *paths):
    r = subprocess.run([sys.executable, "-c", SCRIPT, *paths], cwd=ROOT, capture_output=True,
                       text=True, timeout=900,
                       env=dict(os.environ, GAUSSVDB_CACHE_DIR=str(tmp_path / "cache")))
    assert r.returncode == 0, r.stderr[-4000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_a_file_without_blosc_compiles_no_frame_decoder(tmp_path):
    assert not uses_blosc(SAMPLE)
    got = _compiled(tmp_path, SAMPLE)
    assert got["walk"] == 1 and got["decode"] == 1 and got["values"] >= 1, got
    assert got["blosc_frame"] == got["lz4_block"] == got["planes"] == 0, got


@pytest.mark.slow
def test_a_blosc_file_compiles_its_frame_decoder(tmp_path):
    assert uses_blosc(warmup.FIXTURE)
    got = _compiled(tmp_path, SAMPLE, warmup.FIXTURE)
    assert got["blosc_frame"] == 1 and got["planes"] == 1, got
    assert got["walk"] == 2 and got["decode"] == 2, got  # one per compression, no more


def test_uses_blosc_reads_the_grids_flags(tmp_path):
    assert not uses_blosc(warmup.CACHE_FIXTURE)  # Mantaflow's ZIP setting: no blosc grid
    assert uses_blosc(warmup.FIXTURE)
    bad = tmp_path / "bad.vdb"
    bad.write_bytes(open(SAMPLE, "rb").read()[:200])  # cut inside the first grid
    assert uses_blosc(bad) and uses_blosc(tmp_path / "missing.vdb")  # undecided: True

