#!/usr/bin/env bash
# The GPU checks and figures of the fast path in one run (about 7 minutes on one H200, within a 15-minute lease):
# the CUDA-only tests (tests/test_cuda.py: the actor's CUDA graph), then eager against compile_update=True at full
# size for DDPG, CIC and APT (benchmarks/throughput.py --fast; its table goes into docs/results/throughput_gpu.md).
# Each method takes 3-4 minutes there (a fresh process, compiling, timed updates and learn() on each path): more
# methods need a longer lease, e.g. `bash benchmarks/gpu_check.sh .gpu/ icm rnd`.
#
# A GPU machine of this project has Python 3.12 and torch but no package registry. Bundle the rest first, on a
# machine with the registry, into a folder of the checkout that git ignores (it travels with the checkout):
#   bash <the project's shared gpu/make_site.sh> .gpu/        # .gpu/gpu-site.tar.xz: SB3, dm_control, mujoco, ...
#   bash benchmarks/gpu_check.sh --bundle-pytest .gpu/        # .gpu/gpu-pytest.tar.xz: pytest, pytest-timeout
# then, on the GPU machine, from the checkout:
#   bash benchmarks/gpu_check.sh .gpu/ [METHOD ...]     # default: ddpg cic apt
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "${1:-}" = "--bundle-pytest" ]; then
    out=${2:?usage: gpu_check.sh --bundle-pytest DIR}
    work=$(mktemp -d)
    trap 'rm -rf "$work"' EXIT
    python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        -d "$work/wheels" pytest pluggy iniconfig packaging pytest-timeout
    python3 -m pip install -q --no-deps --no-compile --only-binary=:all: --python-version 3.12 --implementation cp \
        --target "$work/site" "$work"/wheels/*.whl
    tar -cJf "$out/gpu-pytest.tar.xz" -C "$work/site" .
    ls -l "$out/gpu-pytest.tar.xz"
    exit 0
fi
bundle=${1:?usage: gpu_check.sh DIR (the folder of gpu-site.tar.xz and gpu-pytest.tar.xz)}
site=$(mktemp -d)
trap 'rm -rf "$site"' EXIT
for archive in "$bundle"/gpu-site.tar.xz "$bundle"/gpu-pytest.tar.xz; do
    tar -xJf "$archive" -C "$site"
done
export PYTHONPATH=$site:$PWD MUJOCO_GL=disable
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.version.cuda, torch.cuda.get_device_name())"
status=0
python3 -m pytest -q -p no:cacheprovider tests/test_cuda.py || status=$?
shift
methods=("$@")
[ ${#methods[@]} -gt 0 ] || methods=(ddpg cic apt)
timeout 540 python3 benchmarks/throughput.py --device cuda --sizes full --fast --learn-steps 10000 --repeats 10 \
    --methods "${methods[@]}" || status=$?
exit $status
