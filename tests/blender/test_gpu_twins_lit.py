"""Kernel tests of lit volumes and of volumes coloured by a second grid (tests/kernels), run again on
the GPU device (llvmpipe here), every frame drawn by the GPU itself (see test_gpu_twins): the lit
field against quadrature, particles' closest-approach shading and its closeness to the lit field,
the gradient threshold, shadows behind a slab and a wide Gaussian; a second grid changes colour,
not alpha, and a constant one gives one hue, in every mode."""
import pytest
from gpu_twin import OnGPU
from test_color_grid import fire, test_constant_colour_grid_gives_one_hue, test_second_grid_changes_colour_not_alpha  # noqa: F401
from test_render_lit import (  # noqa: F401
    blob,
    test_lit_field_matches_quadrature,
    test_particles_lit_close_to_field_lit,
    test_particles_lit_one_gaussian,
    test_shadows_field_gaussian,
    test_shadows_reference_slab,
    test_threshold_leaves_homogeneous_regions_unlit,
)


@pytest.fixture(scope="module")
def dev(gpu):
    return OnGPU(gpu)
