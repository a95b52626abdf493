#!/bin/sh
# The GPU machine's run (no Blender, no network), one call: unpack the carried EGL/GL packages
# where the machine lacks them, install the carried wheels (moderngl, glcontext, blosc) where the
# Python lacks them, point EGL at NVIDIA's vendor file, make every case from the carried .vdb
# files (benchmarks/gpu_cases.py: numba, its kernels compiled into a temporary cache) and draw
# and time them (benchmarks/gpu_real.py build), all within BUDGET_S.
#   here:  python benchmarks/gpu_real.py prepare    (.whl, and the shared .vdb files in .data)
#          python benchmarks/gpu_real.py payload    (the call's MiB, part by part)
#   there: sh benchmarks/gpu_real.sh --build .data OUT [build options]   (carry .data, .whl, .gl)
#   or, cases made before: sh benchmarks/gpu_real.sh CASES OUT [run options]
# PYTHON: the interpreter (default python3); BUDGET_S: the seconds for it all (default 450: cases
# not made or not timed by then are listed as skipped).
set -e
usage="usage: gpu_real.sh --build DATA OUT [build options] | gpu_real.sh CASES OUT [run options]"
mode=run
if [ "$1" = "--build" ]; then
  mode=build
  shift
fi
src=${1:?$usage}
out=${2:?$usage}
shift 2
py=${PYTHON:-python3}
if [ -d .gl ] && ! ldconfig -p | grep -q libEGL.so.1; then
  for f in .gl/*.deb; do dpkg -x "$f" /; done
  ldconfig
fi
if ! "$py" -c "import moderngl, blosc" 2>/dev/null; then
  "$py" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
  export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
fi
export PYTHONUNBUFFERED=1
nv=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
[ -f "$nv" ] && export __EGL_VENDOR_LIBRARY_FILENAMES="${__EGL_VENDOR_LIBRARY_FILENAMES:-$nv}"
if [ "$mode" = build ]; then
  cache=${GAUSSVDB_CACHE_DIR:-$(mktemp -d /tmp/gaussvdb-kernels-XXXXXX)}
  export GAUSSVDB_CACHE_DIR="$cache" NUMBA_CACHE_DIR="${NUMBA_CACHE_DIR:-$cache/numba}"
  exec "$py" benchmarks/gpu_real.py build "$src" "$out" --budget-s "${BUDGET_S:-450}" "$@"
fi
exec "$py" benchmarks/gpu_real.py run "$src" "$out" --budget-s "${BUDGET_S:-420}" "$@"
