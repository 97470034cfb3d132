#!/usr/bin/env bash
# Installs the libtorch that cac's `tch` feature builds against: pip's `torch==2.9.0` (the
# version tch 0.22 expects) in a venv of its own at $CAC_TORCH_VENV (default
# ~/.cache/cac/torch-2.9.0). About 3 GB to download the first time (CUDA libraries included),
# seconds when present. Then: `. tools/libtorch/env.sh`.
set -euo pipefail
VENV="${CAC_TORCH_VENV:-$HOME/.cache/cac/torch-2.9.0}"
if [ ! -x "$VENV/bin/python" ]; then
    python3 -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install --quiet --disable-pip-version-check torch==2.9.0
"$VENV/bin/python" - <<'PY'
import torch
v = torch.__version__.split("+")[0]
assert v == "2.9.0", f"tch 0.22 needs torch 2.9.0, this venv has {torch.__version__}"
assert torch._C._GLIBCXX_USE_CXX11_ABI, "the wheel must use the C++11 ABI (tools/libtorch/env.sh says so)"
print(f"libtorch {torch.__version__} in {torch.__file__.rsplit('/', 1)[0]}")
PY
