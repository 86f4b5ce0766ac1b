#!/usr/bin/env bash
# The project's one test command (README.md, .ci/run): installs what the tests need when it is
# missing — Mesa's software Vulkan driver, for the headless rendering tests — then builds and runs
# every test once, in release mode (the extraction tests crunch real HDR maps).
set -euo pipefail
cd "$(dirname "$0")/.."

have_lavapipe() {
  ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1 &&
    { ldconfig -p 2>/dev/null | grep -q 'libvulkan\.so\.1'; }
}

if ! have_lavapipe; then
  SUDO=""
  [ "$(id -u)" = 0 ] || SUDO="sudo"
  echo "scripts/test.sh: installing Mesa's software Vulkan driver (mesa-vulkan-drivers)" >&2
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null
fi

# Mesa warns without a runtime dir; a private one is enough.
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"

exec cargo test --release "$@"
