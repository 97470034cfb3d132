#!/usr/bin/env bash
# GPU check of the `gpu` feature on a machine with a Vulkan driver (docs/detectors.md, "GPU"):
# CPU against GPU raw outputs of both TFJS detectors, then GPU timings.
#
#   cargo build --release --features gpu --bin cac
#   CAC=target/release/cac IMAGE=photo.png OUT=gpu-check tools/gpu_check.sh
#
# Needs libvulkan.so.1 and the GPU's Vulkan ICD (NVIDIA: VK_DRIVER_FILES may have to point at
# the driver's nvidia_icd.json), python3 with numpy for the comparison, and the models in the
# cache (`cac models fetch`, or CAC_CACHE_DIR pointing at a copy). The first GPU run of each
# model compiles and autotunes its kernels (tens of seconds); CUBECL_AUTOTUNE_LEVEL=minimal
# shortens that.
set -euo pipefail
CAC=${CAC:-target/release/cac}
IMAGE=${IMAGE:?set IMAGE to a photo}
OUT=${OUT:-gpu-check}
mkdir -p "$OUT"
here=$(cd "$(dirname "$0")" && pwd)
for m in nanodet centernet; do
  CAC_DEVICE=cpu "$CAC" detect "$IMAGE" --model $m --raw "$OUT/$m-cpu.json"
  s=$(date +%s)
  CAC_DEVICE=gpu "$CAC" detect "$IMAGE" --model $m --raw "$OUT/$m-gpu.json"
  echo "$m: first GPU run $(( $(date +%s) - s )) s"
  python3 "$here/raw_cmp.py" "$OUT/$m-gpu.json" "$OUT/$m-cpu.json"
done
CAC_DEVICE=gpu "$CAC" bench detect --runs 10 --csv "$OUT/gpu-detect.csv" \
  --frcnn-csv "$OUT/gpu-frcnn.csv"
