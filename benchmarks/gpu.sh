#!/usr/bin/env bash
# Issue 5's GPU measurements in one run, for a session lent a CUDA device (a few minutes on an
# H100/H200): loss vs pytorch-msssim at 8x3x256x512, then the full-width (31.6 M parameter)
# training step at 256x512, batch 8, with the speed switches added one by one. Prints img/s
# and peak GPU memory. Needs the project installed (pip install -e ".[test]").
set -uo pipefail
cd "$(dirname "$0")/.."
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || exit 1
python -c "import torch; print('torch', torch.__version__, 'cuda', torch.version.cuda)"
python benchmarks/loss.py --device cuda --batch 8 --height 256 --width 512
for switches in "" "--amp bf16" "--amp bf16 --channels-last" "--amp bf16 --channels-last --compile"; do
    echo "== train step: ${switches:-fp32}"
    # shellcheck disable=SC2086  # the switches are meant to split
    python benchmarks/train_step.py --device cuda --width-multiplier 1 --height 256 --width 512 \
        --batch 8 --kernels 3,5,7,11 --repeats 20 $switches
done
