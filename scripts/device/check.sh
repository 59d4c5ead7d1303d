#!/usr/bin/env bash
# The GPU checks, in one call on a machine with an NVIDIA GPU (the `device` tool's H200): the
# GPU tests of crates/nis-cuda, then `nis bench flow --device cuda`, then the same flows in
# PyTorch (eager and torch.compile) on the same card. Results go to $OUT (default target/device-out).
#
# There is no Rust toolchain on that machine: build here first, then carry target/device:
#   scripts/device/build.sh
#   (device tool) run: scripts/device/check.sh, carry target/device
set -uo pipefail
cd "$(dirname "$0")/../.."
OUT=${OUT:-target/device-out}
mkdir -p "$OUT"
BIN=target/device

# CUDA's libraries: the driver's folder, the toolkit's and the nvidia-* Python packages'.
libs=$(python3 - <<'PY'
import glob
pats = ["/usr/local/nvidia/lib64", "/usr/local/cuda/lib64", "/usr/local/cuda/targets/x86_64-linux/lib"]
pats += glob.glob("/usr/local/lib/python3*/dist-packages/nvidia/*/lib")
pats += glob.glob("/opt/torch/.venv/lib/python3*/site-packages/nvidia/*/lib")
pats += glob.glob("/opt/torch/.venv/lib/python3*/site-packages/nvidia/cu13/lib")
print(":".join(p for p in pats if glob.glob(p + "/*.so*")))
PY
)
export LD_LIBRARY_PATH="$libs:${LD_LIBRARY_PATH:-}"

{
  nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader
  echo "LD_LIBRARY_PATH=$LD_LIBRARY_PATH"
  for l in libcuda.so.1 libnvrtc.so.13 libcublas.so.13 libcublasLt.so.13; do
    found=$(echo "$LD_LIBRARY_PATH" | tr ':' '\n' | while read -r d; do [ -e "$d/$l" ] && echo "$d/$l"; done | head -1)
    echo "$l: ${found:-not on the path}"
  done
} 2>&1 | tee "$OUT/machine.txt"

status=0
echo "== GPU tests" | tee "$OUT/tests.txt"
timeout 150 "$BIN/gpu-tests" --include-ignored --nocapture --test-threads 1 2>&1 | tee -a "$OUT/tests.txt" || status=1

if [ "${SANITIZE:-0}" = 1 ]; then
  # Out-of-bounds and misaligned accesses of the kernels (memcheck), then reads of memory never
  # written (initcheck), on the tests that compare with the CPU.
  echo "== compute-sanitizer (memcheck)" | tee "$OUT/sanitizer.txt"
  timeout 120 compute-sanitizer --tool memcheck --error-exitcode 9 "$BIN/gpu-tests" --include-ignored \
    --test-threads 1 gpu_gradient_is_the_cpu_gradient gpu_and_cpu_give_the_same 2>&1 \
    | tail -15 | tee -a "$OUT/sanitizer.txt" || status=1
  timeout 120 compute-sanitizer --tool initcheck --error-exitcode 9 "$BIN/gpu-tests" --include-ignored \
    --test-threads 1 gpu_gradient_is_the_cpu_gradient gpu_and_cpu_give_the_same 2>&1 \
    | tail -15 | tee -a "$OUT/sanitizer.txt" || status=1
fi

if [ "${PROFILE:-0}" = 1 ]; then
  # Per-kernel GPU time of R2's first sampling calls at 2^20 points (Nsight Compute).
  echo "== ncu, R2 sampling at 2^20" | tee "$OUT/profile.txt"
  timeout 150 ncu --clock-control none --launch-count 130 --print-summary per-kernel \
    --metrics gpu__time_duration.sum "$BIN/nis" bench flow --device cuda --only R2 \
    --gpu-batches 1048576 >>"$OUT/profile.txt" 2>&1 || status=1
  grep -E "nis_|gemm|Kernel|duration" "$OUT/profile.txt" | head -40
fi

echo "== nis bench flow --device cuda" | tee "$OUT/bench.txt"
timeout 150 "$BIN/nis" bench flow --device cuda 2>"$OUT/bench.err" | tee -a "$OUT/bench.txt" || status=1

if [ "${SKIP_TORCH:-0}" != 1 ]; then
  echo "== PyTorch on the same card" | tee "$OUT/torch.txt"
  for c in ${TORCH_CONFIGS:-R1 R2}; do
    NIS_TORCH_NO_VENV=1 timeout ${TORCH_TIMEOUT:-150} python3 scripts/bench/bench-torch.py --device cuda --config "$c" \
      --batches 65536,1048576 --compile 2>&1 | tee -a "$OUT/torch.txt" || status=1
  done
fi
exit $status
