#!/usr/bin/env bash
# Installs what lfr needs on a fresh Debian 12 machine: Debian's Embree 3 (libembree-dev),
# numpy for the sample-format reader in docs/tools (the tests run it), and the optional peers
# of `lfr compare`: pyoidn (Intel Open Image Denoise 2.5) and flip-evaluator (HDR-FLIP).
# Idempotent: does nothing when everything is already installed. The optional packages only
# warn when they cannot be installed; `lfr compare` then skips them with a notice.
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
for module in pyoidn:pyoidn flip_evaluator:flip-evaluator; do
  if ! python3 -c "import ${module%%:*}" >/dev/null 2>&1; then
    echo "installing ${module#*:} (optional, for lfr compare) ..." >&2
    python3 -m pip install --quiet "${module#*:}" || echo "warning: could not install ${module#*:}; lfr compare will skip it" >&2
  fi
done
