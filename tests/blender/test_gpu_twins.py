"""Kernel tests that judge images by analytic answers (tests/kernels), run again on the GPU device
(llvmpipe here): each test is imported from its kernel module and gets this module's device
fixtures, and every frame must be drawn by the GPU itself (a frame handed to the CPU fails).
Surfaces: the sphere's silhouette, normal and depth, lights, volumes in front of, behind and around
a surface; clipping: planes along and across the view, two halves, boxes."""
import pytest
from gpu_twin import OnGPU
from test_render_clip import (  # noqa: F401
    blob,
    test_box,
    test_plane_across_view_equals_camera_clip,
    test_plane_along_view_cuts_columns,
    test_two_halves_make_the_whole,
)
from test_render_surface import (  # noqa: F401
    sphere,
    test_headlight_and_point_light,
    test_reference_sphere_silhouette_normal_depth,
    test_volumes_in_front_behind_and_around,
)


@pytest.fixture(scope="module")
def dev(gpu):
    return OnGPU(gpu)


@pytest.fixture(scope="module")
def devices(gpu):
    """As the kernel tests' pair: lists built on the device, and the CPU's lists uploaded."""
    return {True: OnGPU(gpu), False: OnGPU(type(gpu)(gpu_tiles=False))}
