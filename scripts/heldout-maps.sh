#!/usr/bin/env bash
# Fetches the real HDR maps held out from tuning (docs/EVALUATION.md, "Maps held out"): the
# other worlds of the packages tests/data comes from, without the ones tests/data already has. Usage: scripts/heldout-maps.sh [DIR]   (default target/heldout-maps), then
#   cargo run --release -- eval --maps DIR --out DIR/eval --doc /dev/null
# Needs npm and apt-get download (Debian); about 45 MB of downloads.
set -euo pipefail
dir=${1:-target/heldout-maps}
mkdir -p "$dir"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
(cd "$tmp" && npm pack --silent @pmndrs/assets@1.7.0 >/dev/null && tar xzf pmndrs-assets-1.7.0.tgz)
for js in "$tmp"/package/hdri/*.exr.js; do
    name=$(basename "$js" .exr.js)
    sed -E 's/.*base64,([A-Za-z0-9+/=]+).*/\1/' "$js" | base64 -d >"$dir/pm-$name.exr"
done
(cd "$tmp" && apt-get download blender-data >/dev/null 2>&1 &&
    dpkg-deb --fsys-tarfile blender-data_*.deb | tar -x ./usr/share/blender/datafiles/studiolights/world/)
for f in "$tmp"/usr/share/blender/datafiles/studiolights/world/*.exr; do
    cp "$f" "$dir/bl-$(basename "$f")"
done
# Drop the maps tests/data already has (same bytes).
here=$(cd "$(dirname "$0")/.." && pwd)
known=$(sha256sum "$here"/tests/data/*.exr | cut -d' ' -f1)
for f in "$dir"/*.exr; do
    if grep -qxF "$(sha256sum "$f" | cut -d' ' -f1)" <<<"$known"; then rm -f "$f"; fi
done
ls "$dir"/*.exr | wc -l | xargs echo "held-out maps in $dir:"
