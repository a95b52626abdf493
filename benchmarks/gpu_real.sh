#!/bin/sh
# The GPU machine's run (no Blender, no network): unpack the carried EGL/GL packages where the
# machine lacks them, install the carried moderngl and glcontext wheels where the Python lacks
# moderngl, point EGL at NVIDIA's vendor file, draw and time every case (benchmarks/gpu_real.py).
#   here:  python benchmarks/gpu_cases.py .cases; python benchmarks/gpu_real.py prepare
#          python benchmarks/gpu_pack.py .cases .carry      (folders .carry/1, 2, ...: a call each)
#   there: sh benchmarks/gpu_real.sh .carry/N OUT [run options]   (carry .carry/N, .whl and .gl)
# PYTHON: the interpreter (default python3); BUDGET_S: cases not started by then are skipped.
set -e
cases=${1:?usage: gpu_real.sh CASES OUT [run options]}
out=${2:?usage: gpu_real.sh CASES OUT [run options]}
shift 2
py=${PYTHON:-python3}
if [ -d .gl ] && ! ldconfig -p | grep -q libEGL.so.1; then
  for f in .gl/*.deb; do dpkg -x "$f" /; done
  ldconfig
fi
if ! "$py" -c "import moderngl" 2>/dev/null; then
  "$py" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
  export PYTHONPATH=/tmp/site
fi
export PYTHONUNBUFFERED=1
nv=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
[ -f "$nv" ] && export __EGL_VENDOR_LIBRARY_FILENAMES="${__EGL_VENDOR_LIBRARY_FILENAMES:-$nv}"
exec "$py" benchmarks/gpu_real.py run "$cases" "$out" --budget-s "${BUDGET_S:-420}" "$@"
