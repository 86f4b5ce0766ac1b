#!/bin/sh
# Fetches the full-resolution Stanford bunny (34,835 vertices, 69,666 triangles) used by
# `vemlight view --bench`, from Debian's glmark2-data package, into data/bunny.obj (git-ignored).
# Needs apt (Debian/Ubuntu). The scan is the Stanford 3D Scanning Repository's; see
# tests/data/LICENSE-bunny.txt.
set -eu
root=$(cd "$(dirname "$0")/.." && pwd)
out="$root/data/bunny.obj"
if [ -s "$out" ]; then
    echo "$out is already there"
    exit 0
fi
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
cd "$tmp"
apt-get download glmark2-data >/dev/null
dpkg-deb --fsys-tarfile glmark2-data_*.deb | tar -x ./usr/share/glmark2/models/bunny.obj
mkdir -p "$root/data"
mv usr/share/glmark2/models/bunny.obj "$out"
echo "wrote $out ($(grep -c '^f ' "$out") triangles)"
