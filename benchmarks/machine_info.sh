#!/usr/bin/env bash
# The machine a GPU benchmark or study ran on, for its machine.txt (gpu_studies.sh,
# gpu_benchmarks.sh): the date, the GPU or, on a machine without one, its CPU (line 2:
# tables/gpu.py reads it), the host's CPU and cores, Python and the JAX stack, and the
# checkout's commit (on a device copy its git metadata can lag the tree it runs: the study's
# README names the commit).
date -u
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>/dev/null ||
  echo "$(nproc)-core $(lscpu | sed -n 's/^Model name: *//p' | head -1), $(free -g | awk '/Mem/{print $2}') GiB, no GPU"
lscpu | grep -m1 "Model name"; nproc
python3 -c "import sys, jax, flax, optax; print(sys.version.split()[0], 'jax', jax.__version__, 'flax', flax.__version__, 'optax', optax.__version__, jax.devices())"
git rev-parse --short HEAD 2>/dev/null
