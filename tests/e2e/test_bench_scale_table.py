"""bench_scale's Markdown table on hand-made rows: every row has the header's columns, and a render
row gives its work per covered pixel (the series itself is run by hand: minutes to hours)."""
import argparse
import os
import sys

from conftest import ROOT

sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
from bench_scale import markdown  # noqa: E402  (after the sys.path line above)


def test_table_columns_and_work_per_pixel():
    rows = [dict(factor=4, step="render", lod="low", mode="particles", active_voxels=124e6, seconds=2.08,
                 seconds_frame=1.74, seconds_sync=0.15, peak_mb=800.0, gaussians=252369,
                 segments_per_pixel=1123.8),
            dict(factor=4, step="read", active_voxels=124e6, seconds=1.0, peak_mb=1700.0),
            dict(factor=5, step="render", lod="high", mode="particles", failed="MemoryError: x")]
    a = argparse.Namespace(source="x.vdb", factors="4,5", quick=False, lods="low", modes="particles",
                           size=512, no_cycles=True, no_import=True)
    text = markdown(rows, [("read", 0.97)], "x.vdb", a, [1.0, 1.2])
    table = [ln for ln in text.splitlines() if ln.startswith("| x")]
    header = next(ln for ln in text.splitlines() if ln.startswith("| size"))
    assert len(table) == 3 and all(ln.count("|") == header.count("|") for ln in table), table
    assert "segments / px" in header
    assert table[0].rstrip(" |").endswith("1,124")  # the render row's work per covered pixel
    assert "failed: MemoryError: x" in table[2]
