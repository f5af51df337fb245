#!/bin/bash
# Every CUDA check and measurement the open issues ask for, in one call on a lent NVIDIA machine (the device tool's
# `run`): a session's device time is short (minutes), so nothing here is interactive and every step has a time limit.
#
# Prepare on the CPU machine (once per session; nothing there can be fetched):
#   bash benchmarks/gpu_checks.sh prepare     # wheels the device image lacks (.whl/) and the test images (.gpu_data/)
# Then one device call, carrying both (about 50 MiB with the tracked tree, under the 64 MiB limit):
#   run(command="bash benchmarks/gpu_checks.sh", carry=[".whl", ".gpu_data"], timeout_s=540)
# What it writes to $OUT comes back: gpu.txt, cuda_tests.txt, throughput_cuda.md (issue 34: pairs/s at 128^2 and
# 256^2, peak device memory, the data share of a training step), demosaic_speed_cuda.md (issue 35: ms/MP of the
# speed-error family), log.txt. Without a GPU (DEVICE=cpu, for a dry run here) the same steps run on the CPU.
set -o pipefail
cd "$(dirname "$0")/.." || exit 1
ROOT=$PWD

if [ "$1" = "prepare" ]; then
    # the device image has torch, numpy, scipy, scikit-image, matplotlib, h5py, pyyaml, tqdm, tifffile, pytest,
    # hypothesis and pytest-xdist (/work/.library/device/KINDS.md); these are the rest, at constraints.txt's versions
    pins=$(grep -iE '^(kornia|kornia_rs|colour-science|colour-demosaicing|OpenEXR|pypng)==' constraints.txt)
    mkdir -p .whl .gpu_data
    # shellcheck disable=SC2086
    python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
        -d .whl $pins || exit 1
    data=${ISETTORCH_DATA:-../shared/data}
    cp -r "$data/kodak24" "$data/mcmaster18" .gpu_data/ || exit 1
    du -sh .whl .gpu_data
    exit 0
fi

OUT=${OUT:-/tmp/gpu_checks_out}
mkdir -p "$OUT"
DEVICE=${DEVICE:-cuda}
export PYTHONUNBUFFERED=1 PYTHONPATH=$ROOT
if [ -d .whl ] && [ "$DEVICE" = "cuda" ]; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site \
        .whl/*.whl || exit 1
    export PYTHONPATH=$ROOT:/tmp/site
fi
export ISETTORCH_DATA=${ISETTORCH_DATA:-$ROOT/.gpu_data}
exec > >(tee "$OUT/log.txt") 2>&1
PY=${PYTHON:-python3}

echo "== device"
(nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv 2>/dev/null || echo "no nvidia-smi") \
    | tee "$OUT/gpu.txt"
$PY -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), \
torch.cuda.get_device_name(0) if torch.cuda.is_available() else '')" | tee -a "$OUT/gpu.txt"

echo "== CUDA tests (they skip without CUDA): stream = CPU rendering, shipped networks = CPU, demosaic on CUDA"
timeout 180 $PY -m pytest -q -p no:cacheprovider -x \
    tests/data/test_stream.py::test_cuda_stream_matches_cpu_rendering_of_the_same_scene \
    tests/training/test_learned_demosaic.py tests/isp/test_demosaic.py tests/test_bench.py \
    "tests/sensor/test_noise.py::test_poisson_shot_noise_beyond_integer_counts" \
    2>&1 | tail -n 30 | tee "$OUT/cuda_tests.txt"

echo "== issue 34: PairStream throughput on $DEVICE"
count=$([ "$DEVICE" = "cuda" ] && echo 16384 || echo 64)
batch=$([ "$DEVICE" = "cuda" ] && echo 512 || echo 16)  # a GPU needs large batches: ~4,000 kernel launches per batch
timeout 240 $PY benchmarks/throughput.py --stream --device "$DEVICE" --count "$count" --batch "$batch" --repeats 3 \
    --markdown "$OUT/throughput_cuda.md"

echo "== issue 34: PairStream at 128^2 in larger batches (per-batch launch overhead amortised; no training step)"
big=$([ "$DEVICE" = "cuda" ] && echo 2048 || echo 32)
timeout 90 $PY benchmarks/throughput.py --stream --device "$DEVICE" --count $((big * 8)) --batch "$big" --repeats 3 \
    --stream-sizes 128 --no-share --markdown "$OUT/throughput_cuda.md"

echo "== issue 35: demosaic speed-error family on $DEVICE"
timeout 240 $PY benchmarks/demosaic_noise_speed.py speed --device "$DEVICE" --threads 8 --rounds 1 -q \
    --out "$OUT/demosaic_speed_cuda.md"
echo "== done"
