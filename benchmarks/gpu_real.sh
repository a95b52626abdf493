#!/bin/sh
# The GPU machine's run (no Blender, no network): unpack the carried EGL/GL packages where the
# machine lacks them, install the carried moderngl and glcontext wheels, point EGL at NVIDIA's
# vendor file, draw and time every case (benchmarks/gpu_real.py).
#   here:  python benchmarks/gpu_cases.py CASES ...; python benchmarks/gpu_real.py prepare CASES --wheels .whl
#   there: sh benchmarks/gpu_real.sh CASES OUT      (carry CASES, .whl and, if needed, .gl)
set -e
cases=${1:?usage: gpu_real.sh CASES OUT}
out=${2:?usage: gpu_real.sh CASES OUT}
if [ -d .gl ] && ! ldconfig -p | grep -q libEGL.so.1; then
  for f in .gl/*.deb; do dpkg -x "$f" /; done
  ldconfig
fi
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH=/tmp/site PYTHONUNBUFFERED=1
nv=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
[ -f "$nv" ] && export __EGL_VENDOR_LIBRARY_FILENAMES="${__EGL_VENDOR_LIBRARY_FILENAMES:-$nv}"
exec python3 benchmarks/gpu_real.py run "$cases" "$out" --budget-s "${BUDGET_S:-420}"
