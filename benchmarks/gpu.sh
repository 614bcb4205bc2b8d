#!/usr/bin/env bash
# Issue 5's GPU measurements in one run, for a session lent a CUDA device (a few minutes on an
# H100/H200): loss vs pytorch-msssim at 8x3x256x512, then the full-width (31.6 M parameter)
# training step at 256x512, batch 8, with the speed switches added one by one, and whole
# training runs (loader, host reads of the loss). Prints img/s and peak GPU memory. Needs the
# project installed (pip install -e ".[test]").
set -uo pipefail
cd "$(dirname "$0")/.."
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || exit 1
python -c "import torch; print('torch', torch.__version__, 'cuda', torch.version.cuda)"
python benchmarks/loss.py --device cuda --batch 8 --height 256 --width 512
train_step() {
    echo "== train step: ${*:-fp32}"
    python benchmarks/train_step.py --device cuda --width-multiplier 1 --height 256 --width 512 \
        --batch 8 --kernels 3,5,7,11 --repeats 20 "$@"
}
train_step
train_step --amp bf16
train_step --amp bf16 --channels-last --profile 10
echo "== training loop (loader with 8 workers, host reads of the loss every step vs every 50)"
python benchmarks/train_loop.py --device cuda --width-multiplier 1 --height 256 --width 512 --batch 8 \
    --pairs 400 --epochs 2 --workers 8 --repeats 2 --amp bf16 --channels-last
train_step --amp bf16 --channels-last --compile  # last: compiling takes the longest
