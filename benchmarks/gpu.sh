#!/usr/bin/env bash
# Issue 5's GPU measurements in one run, for a session lent a CUDA device (a few minutes on an
# H100/H200): loss vs pytorch-msssim at 8x3x256x512, then the full-width (31.6 M parameter)
# training step at 256x512, batch 8, with the speed switches added one by one, and whole
# training runs (loader, host reads of the loss). Prints img/s and peak GPU memory.
#
# The GPU image has torch, numpy, OpenCV, pandas, PyYAML and tqdm, but neither this project
# nor pytorch-msssim, and no network: the scripts import msdepth from src/, and wheels carried
# in .whl/ are installed to /tmp/site first. Prepare once, here:
#   echo /.whl/ >> .git/info/exclude
#   python -m pip download --no-deps --only-binary=:all: --python-version 3.12 -d .whl pytorch-msssim==1.0.0
# then: run(command="bash benchmarks/gpu.sh", carry=[".whl"], timeout_s=600).
set -uo pipefail
cd "$(dirname "$0")/.."
export PYTHONUNBUFFERED=1 PYTHONPATH="$PWD/src${PYTHONPATH:+:$PYTHONPATH}"
if compgen -G ".whl/*.whl" >/dev/null; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl &&
        export PYTHONPATH="/tmp/site:$PYTHONPATH"
fi
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || exit 1
python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.version.cuda)"
python3 benchmarks/loss.py --device cuda --batch 8 --height 256 --width 512
train_step() {
    echo "== train step: ${*:-fp32}"
    python3 benchmarks/train_step.py --device cuda --width-multiplier 1 --height 256 --width 512 \
        --batch 8 --kernels 3,5,7,11 --repeats 20 "$@"
}
train_step
train_step --amp bf16
train_step --amp bf16 --channels-last --profile 10
echo "== training loop (loader with 8 workers, host reads of the loss every step vs every 50)"
python3 benchmarks/train_loop.py --device cuda --width-multiplier 1 --height 256 --width 512 --batch 8 \
    --pairs 400 --epochs 2 --workers 8 --repeats 2 --amp bf16 --channels-last
train_step --amp bf16 --channels-last --compile  # last: compiling takes the longest
