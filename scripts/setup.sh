#!/usr/bin/env bash
# Set up kitchenbot on a fresh Debian/Ubuntu machine: Debian packages, a virtual environment and the
# Python packages. Called by `make setup` (and so by `make demo` / `make test`); safe to run again.
set -euo pipefail
PYTHON=${1:-python3}
VENV=${2:-.venv}

# 1. Debian packages. open3d needs libusb; depthai wants it too. chromium: the operator page's browser tests
# (tests/executive/test_operator_page.py drive it headless through Playwright).
DEB_PACKAGES="libusb-1.0-0 libgomp1 chromium"
missing=""
for p in $DEB_PACKAGES; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
if [ -n "$missing" ]; then
  if [ "$(id -u)" = "0" ]; then
    echo "setup: installing Debian packages:$missing"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $missing >/dev/null
  elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then
    sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $missing >/dev/null
  else
    echo "setup: missing Debian packages:$missing" >&2
    echo "setup: run 'sudo apt-get install$missing' and try again." >&2
    exit 1
  fi
fi

# 2. Python >= 3.11 and a virtual environment.
"$PYTHON" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)' || {
  echo "setup: $PYTHON is $($PYTHON --version 2>&1); kitchenbot needs Python 3.11 or newer." >&2; exit 1; }
[ -x "$VENV/bin/python" ] || "$PYTHON" -m venv "$VENV"

# 3. Python packages (the project itself in editable mode, with the test tools and the learned backends).
# torch first and pinned: this exact version resolves to the CPU build; any other spec would pull the CUDA
# wheels (gigabytes). Skipped when already installed, so a second run stays quick.
log=$(mktemp)
TORCH_VERSION=2.13.0
if ! "$VENV/bin/python" -c "import torch, sys; sys.exit(torch.__version__.split('+')[0] != '$TORCH_VERSION')" 2>/dev/null; then
  echo "setup: installing torch==$TORCH_VERSION (CPU build)"
  # Elsewhere, point KITCHENBOT_TORCH_INDEX at PyTorch's CPU wheel index to avoid the CUDA build.
  torch_index=()
  [ -n "${KITCHENBOT_TORCH_INDEX:-}" ] && torch_index=(--index-url "$KITCHENBOT_TORCH_INDEX")
  if ! "$VENV/bin/python" -m pip install -q "${torch_index[@]}" "torch==$TORCH_VERSION" >"$log" 2>&1; then
    grep -v "^WARNING: Location" "$log" >&2; rm -f "$log"
    echo "setup: pip could not install torch==$TORCH_VERSION (see above)." >&2; exit 1
  fi
fi
if ! "$VENV/bin/python" -m pip install -q -e ".[dev,learned]" >"$log" 2>&1; then
  grep -v "^WARNING: Location" "$log" >&2; rm -f "$log"
  echo "setup: pip could not install the Python packages (see above)." >&2; exit 1
fi
rm -f "$log"
"$VENV/bin/python" -c "import kitchenbot, open3d, pinocchio, ompl, torch, transformers, playwright" || {
  echo "setup: the Python packages did not install; see the pip output above." >&2; exit 1; }
echo "setup: ready ($VENV)"
