#!/usr/bin/env bash
# The Python packages that `benchmarks/bench_gpu.py` needs and the lent accelerator machine's image lacks (it has
# jax with CUDA, flax, optax, chex, orbax, numpy and scipy; not MuJoCo or flashbax), downloaded here as wheels for its
# Python 3.12 into .whl/ (ignored by git). The device command then installs them from there; see bench_gpu.py.
set -euo pipefail
cd "$(dirname "$0")/.."
mkdir -p .git/info
grep -qx "/.whl/" .git/info/exclude 2>/dev/null || echo "/.whl/" >> .git/info/exclude
python3 -m pip download --quiet --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
    --platform manylinux2014_x86_64 --platform manylinux1_x86_64 -d .whl \
    flashbax==0.1.3 mujoco==4.0.0 mujoco-core==4.0.0 mujoco-studio==4.0.0 mujoco-mjx==3.17.0 glfw==2.11.0
du -sh .whl
