"""Conversion in bounded memory: the field error and the compact encoding, computed a chunk at a
time, give exactly what one pass over the whole set gives; a chunked error holds less memory."""
import dataclasses
import tracemalloc

import numpy as np
import pytest

from kernels.lod import build_lod, encode_compact, field_error
from kernels.lod import encoding as enc_mod
from kernels.lod import mixture as E
from kernels.lod.synthetic import random_sparse_grid


def with_tiles(g):
    g.tile_origins = np.array([[96, 0, 0], [-256, -256, 128]], np.int32)  # an 8^3 and a 128^3 tile
    g.tile_sizes = np.array([8, 128], np.int32)
    g.tile_values = np.array([0.3, 0.6], np.float32)
    g.tile_active = np.array([True, True])
    return g


def one_pass(grid, gs):
    """The evaluation as one list of pairs over every cell, axis terms computed directly."""
    st = E.setup(grid, gs)
    w = gs.values.astype(np.float64) * gs.amplitudes.astype(np.float64)
    return E._eval_cells(st["corg"], st["cmask"], st["cref"], st["cstart"], st["pg"], st["cent"],
                         st["sig"], w, st["k"], *E._NO_TABLES, *E._NO_LATTICE, *E.NO_VALUES)


CASES = [("high", "fog_volume"), ("low", "fog_volume"), ("variance", "fog_volume"),
         ("medium", "level_set"), ("merged", "fog_volume")]


@pytest.mark.parametrize("preset,cls", CASES)
def test_chunked_error_equals_one_pass(preset, cls):
    g = random_sparse_grid(11, n_leaves=40, span=4, density=0.6, grid_class=cls)
    if cls == "fog_volume":
        g = with_tiles(g)
    gs = build_lod(g, preset)
    ref = one_pass(g, gs)
    first = None
    for chunk in (1, 7, 10 ** 9):
        st, got = E._evaluate(g, gs, E.DEFAULT_K, chunk, lattice=False)
        for a, b in zip(ref, got):
            assert np.array_equal(a, b), (preset, chunk)
        assert st["pairs"] == len(E.setup(g, gs)["pg"])
        # the lattice path: the same figures but for the order of the additions, whatever the chunk
        _, lat = E._evaluate(g, gs, E.DEFAULT_K, chunk)
        for a, b in zip(ref, lat):
            np.testing.assert_allclose(b, a, rtol=1e-11, atol=1e-300)
        first = first or lat
        for a, b in zip(first, lat):
            assert np.array_equal(a, b), (preset, chunk)
    assert field_error(g, gs, chunk=3) == {**field_error(g, gs), "seconds": pytest.approx(0, abs=1e9)}


def test_off_lattice_centres_take_the_direct_terms():
    g = random_sparse_grid(5, n_leaves=20, span=3)
    gs = build_lod(g, "high")
    gs = dataclasses.replace(gs, offsets=gs.offsets + np.float32(0.25))  # no half-voxel lattice
    _, got = E._evaluate(g, gs, E.DEFAULT_K, 4)  # no lattice class: all on the pair lists
    for a, b in zip(one_pass(g, gs), got):
        assert np.array_equal(a, b)
    assert got[0].sum() > 0


@pytest.mark.parametrize("preset,cls", CASES + [("high", "level_set")])
def test_chunked_encoding_equals_one_pass(preset, cls, monkeypatch):
    g = random_sparse_grid(3, n_leaves=60, span=5, grid_class=cls)
    gs = build_lod(g, preset)
    whole = encode_compact(gs)
    for step in (8, 24, 1 << 30):
        monkeypatch.setattr(enc_mod._chunks, "__defaults__", (step,))
        parts = encode_compact(gs)
        assert list(parts) == list(whole)
        for k in whole:
            assert parts[k].dtype == whole[k].dtype and np.array_equal(parts[k], whole[k]), (k, step)


def test_chunked_error_holds_less_memory():
    g = random_sparse_grid(2, n_leaves=600, span=6, density=0.9, dense_frac=0.8)
    gs = build_lod(g, "high")
    field_error(g, gs, chunk=16)  # compiled before measuring

    def peak(chunk):
        tracemalloc.start()
        e = field_error(g, gs, chunk=chunk)
        p = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return p, e

    small, e_small = peak(16)
    big, e_big = peak(10 ** 9)
    assert e_small["rmse"] == e_big["rmse"]
    # one chunk holds every cell's reference row (2 kB each) at once; 16 cells at a time do not
    assert small < 0.5 * big, (small, big)
    assert big - small > 0.5 * 600 * 2048
