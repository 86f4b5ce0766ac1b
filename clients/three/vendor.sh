#!/usr/bin/env bash
# Regenerates vendor/: three.js's ES module, bundled into one minified file, and its licence, from
# the version pinned in package.json (node_modules, `npm ci` first). The daemon embeds these files
# (src/server/demo.rs), so building it needs neither npm nor a network; run this after changing
# the pinned version, and commit the result.
set -euo pipefail
cd "$(dirname "$0")"
[ -d node_modules/three ] || npm ci
version="$(node -p 'require("./node_modules/three/package.json").version')"
pinned="$(node -p 'require("./package.json").devDependencies.three')"
[ "$version" = "$pinned" ] || { echo "node_modules has three $version, package.json pins $pinned: run npm ci" >&2; exit 1; }
mkdir -p vendor
# build/three.module.js imports build/three.core.js: bundle the two into one file.
npx esbuild node_modules/three/build/three.module.js --bundle --minify --format=esm \
  --legal-comments=inline --log-level=warning --outfile=vendor/three.module.min.js
cp node_modules/three/LICENSE vendor/LICENSE
echo "$version" > vendor/VERSION
echo "vendor/: three $version, $(wc -c < vendor/three.module.min.js) bytes"
