#!/usr/bin/env bash
# The project's one test command (README.md, .ci/run): installs what the tests need when it is
# missing — Mesa's software Vulkan driver, for the headless rendering tests, Chromium, for the
# live view's browser test, and nats-server, the broker of the publishing tests — then builds and runs every test once, in release mode (the
# extraction tests crunch real HDR maps). Arguments go to `cargo test` (a filter, say).
set -euo pipefail
cd "$(dirname "$0")/.."

have_lavapipe() {
  ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1 &&
    { ldconfig -p 2>/dev/null | grep -q 'libvulkan\.so\.1'; }
}

have_chromium() {
  command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1
}

missing=()
have_lavapipe || missing+=(mesa-vulkan-drivers libvulkan1)
have_chromium || missing+=(chromium)
have_nats() {
  command -v nats-server >/dev/null 2>&1 || [ -x /usr/sbin/nats-server ]
}
have_nats || missing+=(nats-server)
if [ ${#missing[@]} -gt 0 ]; then
  SUDO=""
  [ "$(id -u)" = 0 ] || SUDO="sudo"
  echo "scripts/test.sh: installing ${missing[*]}" >&2
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
fi
# The live view's browser test runs, not skips (tests/viewer_browser.rs).
export VEMLIGHT_REQUIRE_BROWSER=1
# And the broker tests run, not skip (tests/common/broker.rs).
export VEMLIGHT_REQUIRE_BROKER=1

# Mesa warns without a runtime dir; a private one is enough.
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"

# A whole run (no test filter given) also builds the benchmarks, so one that no longer compiles
# fails here, and runs the two commands behind the docs' figures once, small: `vemlight bench`
# (two short rounds) and `vemlight eval --quick`, writing into a scratch folder, not docs/.
if [ $# -eq 0 ]; then
  # Every target in the release profile at once (benches too), so `cargo test --release` below
  # reuses the build instead of compiling the library a second time for the bench profile.
  cargo build --release --all-targets
  scratch="$(mktemp -d)"
  cp docs/EVALUATION.md "$scratch/"
  target/release/vemlight bench --rounds 2 --per-round 3
  target/release/vemlight eval --quick --out "$scratch" --doc "$scratch/EVALUATION.md"
  rm -rf "$scratch"
fi

exec cargo test --release "$@"
