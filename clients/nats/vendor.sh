#!/usr/bin/env bash
# Regenerates vendor/: the NATS JavaScript client (@nats-io/nats-core, with the nkeys, nuid and
# tweetnacl code it pulls in) bundled into one minified ES module, and the licences of everything
# in it, from the version pinned in package.json (node_modules, `npm ci` first). The daemon embeds
# these files (src/server/handlers.rs) for the live view's broker mode (`GET /?nats=ws://…`), so
# building it needs neither npm nor a network; run this after changing the pinned version, and
# commit the result.
set -euo pipefail
cd "$(dirname "$0")"
[ -d node_modules/@nats-io/nats-core ] || npm ci
version="$(node -p 'require("./node_modules/@nats-io/nats-core/package.json").version')"
pinned="$(node -p 'require("./package.json").devDependencies["@nats-io/nats-core"]')"
[ "$version" = "$pinned" ] || { echo "node_modules has @nats-io/nats-core $version, package.json pins $pinned: run npm ci" >&2; exit 1; }
mkdir -p vendor
# The package is CommonJS: an ES entry re-exporting its public names by name gives the bundle
# named exports (`import { wsconnect } from …`).
names="$(node -p 'Object.keys(require("@nats-io/nats-core")).join(", ")')"
echo "export { $names } from \"@nats-io/nats-core\";" |
  npx esbuild --bundle --minify --format=esm --platform=browser --legal-comments=inline \
    --sourcefile=nats-core-entry.js --log-level=warning --outfile=vendor/nats-core.min.js
{
  for pkg in @nats-io/nats-core @nats-io/nkeys @nats-io/nuid tweetnacl; do
    v="$(node -p "require('./node_modules/$pkg/package.json').version")"
    printf '%s %s\n%s\n\n' "$pkg" "$v" "------------------------------------------------------------------------"
    cat "node_modules/$pkg/LICENSE"
    printf '\n\n'
  done
} > vendor/LICENSE
echo "$version" > vendor/VERSION
echo "vendor/: @nats-io/nats-core $version, $(wc -c < vendor/nats-core.min.js) bytes"
