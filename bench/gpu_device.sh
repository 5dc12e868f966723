#!/usr/bin/env bash
# The wgpu rasterizer on a lent GPU machine, in one call: the render tests with
# CI=true, then the shader variants at 50 M points (three orders) and 500 M
# points (Morton order), interleaved, and the frame with and without ids.
#
# Here, first (the machine has no Rust and no Vulkan loader):
#   cargo build --release --bench render && cargo test --test render --no-run
#   mkdir -p .devbin && cp target/release/deps/render-<hash> .devbin/render
#   cp target/debug/deps/render-<hash> .devbin/render_tests && strip .devbin/*
#   .gl/: the loader packages, as /work/.library/device/README.md says
# Then, through the device tool, carrying .gl and .devbin:
#   bash bench/gpu_device.sh            (logs under $OUT)
# Variant names: see `variants()` in benches/render.rs.
set -uo pipefail
OUT=${OUT:-$(mktemp -d)}
for f in .gl/*.deb; do dpkg -x "$f" /; done
ldconfig
export NODEVICE_SELECT=1
nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.sm,clocks.max.sm --format=csv | tee "$OUT/gpu.txt"
if ! ls /usr/share/vulkan/icd.d/*nvidia* /etc/vulkan/icd.d/*nvidia* >/dev/null 2>&1; then
  export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
  export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
fi
start=$(date +%s)
stamp() { echo "[$(($(date +%s) - start)) s] $*"; }

stamp "render tests"
CI=true timeout 240 .devbin/render_tests --test-threads 4 2>&1 | tee "$OUT/tests.txt" | grep -E "^test result|FAILED|panicked|gpu:" | head -20

VARIANTS=${VARIANTS:-default,ppt8+pretest,ppt32+pretest+merge,ppt4+pretest+sg,ppt8+pretest+sg,ppt16+pretest+sg,ppt8+sg,ppt8+pretest+sg+seg}
stamp "50 M points, three orders"
PCIMG_RENDER_AB=50000000 PCIMG_RENDER_CPU=0 PCIMG_RENDER_ROUNDS=9 PCIMG_RENDER_VARIANTS=$VARIANTS \
  timeout 300 .devbin/render 2>&1 | tee "$OUT/ab50M.txt"

stamp "500 M points, Morton order"
PCIMG_RENDER_AB=500000000 PCIMG_RENDER_CPU=0 PCIMG_RENDER_ROUNDS=9 PCIMG_RENDER_ORDERS=morton \
  PCIMG_RENDER_VARIANTS=$VARIANTS timeout 300 .devbin/render 2>&1 | tee "$OUT/ab500M.txt"

if [ "${IDS:-1}" = 1 ]; then
  stamp "500 M points, with and without ids (CPU rows too)"
  PCIMG_RENDER_IDS=500000000 timeout 300 .devbin/render 2>&1 | tee "$OUT/ids500M.txt"
fi
stamp done
