#!/usr/bin/env bash
# The losses' own optimum on the real KITTI object pair, every variant and smoothness weight,
# scored against the pair's Velodyne scan (the table of studies/results/optimum/kitti_pair.md):
#   bash studies/kitti_pair.sh [OUT]        (OUT: a scratch folder, default /tmp/kitti_pair)
# Each run: msdepth optimum at 188 x 622 (half size, for time), outputs at 375 x 1242.
set -euo pipefail
cd "$(dirname "$0")/.."
S=../shared/real-samples/kitti-object-pair
OUT=${1:-/tmp/kitti_pair}
for w in 3 10 30; do
  for v in ssim msssim:3 msssim:5 msssim:7 msssim:11; do
    name=${v/:/_k}_w$w
    set -- --variant "${v%%:*}" --set optimum.smoothness_weight=$w
    [[ $v == msssim:* ]] && set -- "$@" --set msssim.kernel_size=${v#*:}
    python -m msdepth optimum $S/left.png $S/right.png "$@" --out "$OUT/$name" --quiet \
      --focal 721.5377 --baseline 0.5327 --height 188 --width 622
  done
done
python studies/score_lidar.py --scan $S/lidar.bin --calib $S/calib.txt "$OUT"/*/left_*_depth.npy
