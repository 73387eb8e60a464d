#!/usr/bin/env bash
# Installs what lfr needs on a fresh Debian 12 machine: Debian's Embree 3 (libembree-dev).
# Idempotent: does nothing when it is already installed.
set -euo pipefail
if dpkg -s libembree-dev >/dev/null 2>&1; then
  exit 0
fi
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
echo "installing libembree-dev (Embree 3) ..." >&2
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get install -y --no-install-recommends libembree-dev >/dev/null 2>&1 || {
  $SUDO apt-get update >/dev/null
  $SUDO apt-get install -y --no-install-recommends libembree-dev
}
