#!/usr/bin/env bash
# Installs what lfr needs on a fresh Debian 12 machine: Debian's Embree 3 (libembree-dev), and
# numpy for the sample-format reader in docs/tools (the tests run it).
# Idempotent: does nothing when both are already installed.
set -euo pipefail
if ! dpkg -s libembree-dev >/dev/null 2>&1; then
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
  echo "installing libembree-dev (Embree 3) ..." >&2
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get install -y --no-install-recommends libembree-dev >/dev/null 2>&1 || {
    $SUDO apt-get update >/dev/null
    $SUDO apt-get install -y --no-install-recommends libembree-dev
  }
fi
if ! python3 -c "import numpy" >/dev/null 2>&1; then
  echo "installing numpy ..." >&2
  python3 -m pip install --quiet numpy
fi
