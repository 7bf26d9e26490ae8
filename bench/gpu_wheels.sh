#!/usr/bin/env bash
# The wheels a lent GPU machine lacks for bench/gpu_check.py, into .gpu_wheels/ (git-ignored), to
# carry there: its image holds torch with CUDA, numpy, JAX, optimistix, OpenCV, matplotlib and
# pytest, but not Dr.Jit (the compiled bounce, whose CUDA backend the check's `kernels` compares
# with eager torch), kornia, trimesh, embreex or OpenEXR, and it reaches no package index. About
# 30 MB, under the 64 MiB that travels with the working tree. warp-lang (150 MB) and Mitsuba do not
# fit: their checks are listed as skipped.
#
#     bash bench/gpu_wheels.sh [PYTHON_VERSION]      # default 3.12, the GPU image's python3
#
# Then, on the GPU machine (the device tool's run, carrying .gpu_wheels), one command:
#
#     python3 -m pip install -q --no-index --no-deps .gpu_wheels/*.whl &&
#     python3 -m pip install -q --no-index --no-deps --no-build-isolation -e . &&
#     PYTHONUNBUFFERED=1 python3 bench/gpu_check.py --out $OUT/gpu
set -euo pipefail
cd "$(dirname "$0")/.."
version="${1:-3.12}"
drjit="$(python -c 'import drjit; print(drjit.__version__)' 2>/dev/null || echo 1.5.0)"  # the Dr.Jit this project is tested with
rm -rf .gpu_wheels && mkdir .gpu_wheels
python -m pip download --quiet --no-deps --only-binary=:all: --python-version "$version" \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 --platform any \
    -d .gpu_wheels "drjit==$drjit" kornia kornia_rs trimesh embreex OpenEXR
ls -l .gpu_wheels
du -sh .gpu_wheels
