#!/bin/bash
# Every CUDA check and measurement the open issues ask for, in one call on a lent NVIDIA machine (the device tool's
# `run`): a session's device time is short (minutes), so nothing here is interactive and every step has a time limit.
#
# Prepare on the CPU machine (once per session; nothing there can be fetched):
#   bash benchmarks/gpu_checks.sh prepare     # wheels the device image lacks (.whl/) and the test images (.gpu_data/)
# Then one device call, carrying both (about 61 MiB with the tracked tree, under the 64 MiB limit):
#   run(command="bash benchmarks/gpu_checks.sh", carry=[".whl", ".gpu_data"], timeout_s=540)
# (2026-11-30 on an H200: about 300 s of run and 90 s of machine start; results in THROUGHPUT.md,
# DEMOSAIC_SPEED_CUDA.md and docs/camera_design.md.)
# What it writes to $OUT comes back: gpu.txt, cuda_tests.txt, cuda_smoke.txt, throughput_cuda.md (issue 34: pairs/s at 128^2 and
# 256^2, peak device memory, the data share of a training step), demosaic_speed_cuda.md (issue 35: ms/MP of the
# speed-error family), codesign_cuda.txt (issue 36: the design trainer's steps/s on the device), log.txt. Without a GPU
# (DEVICE=cpu, for a dry run here) the same steps run on the CPU. Every step has its own time limit and the whole run
# stops starting steps at BUDGET_S (default 480 s) after its start.
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
START=$SECONDS
BUDGET_S=${BUDGET_S:-480}
# limit SECONDS: a step's time limit, cut to what is left of the budget (at least 1 s)
limit() { local left=$((BUDGET_S - (SECONDS - START))); [ "$left" -lt "$1" ] && echo $((left > 1 ? left : 1)) \
    || echo "$1"; }

echo "== device"
(nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv 2>/dev/null || echo "no nvidia-smi") \
    | tee "$OUT/gpu.txt"
$PY -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(), \
torch.cuda.get_device_name(0) if torch.cuda.is_available() else '')" | tee -a "$OUT/gpu.txt"

echo "== CUDA tests (they skip without CUDA): stream = CPU rendering, shipped networks = CPU, demosaic on CUDA"
timeout "$(limit 150)" $PY -m pytest -q -p no:cacheprovider -n 8 \
    tests/data/test_stream.py::test_cuda_stream_matches_cpu_rendering_of_the_same_scene \
    tests/training/test_codesign.py::test_a_run_on_cuda_renders_as_the_cpu_does_and_resumes_on_the_cpu \
    tests/data/test_stream_cameras.py \
    tests/training/test_learned_demosaic.py tests/isp/test_demosaic.py tests/test_bench.py \
    "tests/sensor/test_noise.py::test_poisson_shot_noise_beyond_integer_counts" \
    2>&1 | tail -n 30 | tee "$OUT/cuda_tests.txt"

echo "== CUDA smoke of the device paths the suite's CUDA cases do not reach (PASS / FAIL per check)"
timeout "$(limit 170)" $PY benchmarks/cuda_smoke.py --device "$DEVICE" --out "$OUT/cuda_smoke.txt" 2>&1 \
    | grep -E "^(PASS|FAIL)"

echo "== issue 34: PairStream throughput on $DEVICE"
# a GPU needs large batches (~4,000 kernel launches per batch), but a 128^2 pair with all targets holds ~92 MB of
# device memory at the peak and a 256^2 pair ~300 MB (H200, 2026-11-30: batch 512 at 256^2 and 2048 at 128^2 ran
# out of its 140 GB); so 128^2 at batch 1024, 256^2 (with the training step's data share) at batch 128
big=$([ "$DEVICE" = "cuda" ] && echo 1024 || echo 32)
timeout "$(limit 70)" $PY benchmarks/throughput.py --stream --device "$DEVICE" --count $((big * 4)) --batch "$big" \
    --repeats 3 --stream-sizes 128 --stream-batches --no-share --markdown "$OUT/throughput_cuda.md"
batch=$([ "$DEVICE" = "cuda" ] && echo 128 || echo 16)
timeout "$(limit 100)" $PY benchmarks/throughput.py --stream --device "$DEVICE" --count $((batch * 8)) \
    --batch "$batch" --repeats 3 --stream-sizes 256 --stream-batches --markdown "$OUT/throughput_cuda.md"

echo "== issue 35: demosaic speed-error family on $DEVICE"
timeout "$(limit 150)" $PY benchmarks/demosaic_noise_speed.py speed --device "$DEVICE" --threads 8 --rounds 1 -q \
    --out "$OUT/demosaic_speed_cuda.md"

echo "== issue 36: the design trainer on $DEVICE (the shipped learned recipe without its CPU predesign; steps/s)"
for batch in 16 64; do
    steps=$([ "$DEVICE" = "cuda" ] && echo $((14400 / batch)) || echo 30)  # H200: 24 steps/s at 16, 12 at 64
    timeout "$(limit 75)" $PY training/codesign.py --config configs/train/codesign_learned.yaml --quiet --set \
        device="$DEVICE" threads=8 optim.steps=$steps data.batch=$batch val.every=0 predesign.steps=0 \
        out=/tmp/codesign_b$batch 2>&1 | tail -n 1 | sed "s/^/batch $batch: /" | tee -a "$OUT/codesign_cuda.txt"
    # the last step's row: its "seconds" is the training time without the final validation
    (head -n 1 /tmp/codesign_b$batch/history.csv; tail -n 1 /tmp/codesign_b$batch/history.csv) 2>/dev/null \
        | tee -a "$OUT/codesign_cuda.txt"
done
echo "== done"
