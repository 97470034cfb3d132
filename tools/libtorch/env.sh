# Source this to build or run cac's libtorch fast path (`cargo … --features tch`).
#
# tch 0.22 (under burn's LibTorch backend) builds against libtorch 2.9.0; the pip wheel
# `torch==2.9.0` ships it (CPU kernels, and CUDA 12.8 for `CAC_DEVICE=cuda`). It lives in a venv of
# its own, so the torch the test fixtures use (tools/onnx, tools/torchvision_oracle.py) is
# untouched. `tools/libtorch/install.sh` makes the venv.
#
#   . tools/libtorch/env.sh && cargo build --release --features tch && target/release/cac demo
CAC_TORCH_VENV="${CAC_TORCH_VENV:-$HOME/.cache/cac/torch-2.9.0}"
_cac_torch="$CAC_TORCH_VENV/lib/python3.11/site-packages/torch"
if [ ! -f "$_cac_torch/lib/libtorch_cpu.so" ]; then
    _cac_torch="$( (ls -d "$CAC_TORCH_VENV"/lib/python3*/site-packages/torch 2>/dev/null || true) | head -n1)"
fi
if [ -z "$_cac_torch" ] || [ ! -f "$_cac_torch/lib/libtorch_cpu.so" ]; then
    echo "tools/libtorch/env.sh: no torch 2.9.0 in $CAC_TORCH_VENV (run tools/libtorch/install.sh)" >&2
    return 1 2>/dev/null || exit 1
fi
# torch-sys reads the wheel's headers and libraries directly (no Python on PATH needed); the
# wheel is built with the C++11 ABI.
export LIBTORCH="$_cac_torch"
export LIBTORCH_CXX11_ABI=1
export LD_LIBRARY_PATH="$_cac_torch/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
unset _cac_torch
