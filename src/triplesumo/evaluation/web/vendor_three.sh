#!/usr/bin/env bash
# Rebuild three.min.js, the three.js that `triplesumo view` inlines into its pages, from npm:
# three (MIT, its LICENSE kept beside as three-LICENSE) and its OrbitControls addon, bundled and
# minified by esbuild into one classic script that defines the global THREE (a classic script
# runs from file:// and inside an iframe, with no import map). Needs node and npm.
set -euo pipefail
THREE_VERSION=0.187.0
ESBUILD_VERSION=0.28.2
here="$(cd "$(dirname "$0")" && pwd)"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
cd "$tmp"
npm init -y >/dev/null
npm install --no-audit --no-fund --silent "three@$THREE_VERSION" "esbuild@$ESBUILD_VERSION"
cat > entry.js <<'JS'
export * from 'three';
export { OrbitControls } from 'three/addons/controls/OrbitControls.js';
JS
./node_modules/.bin/esbuild entry.js --bundle --minify --format=iife --global-name=THREE \
  --legal-comments=inline --outfile="$here/three.min.js"
cp node_modules/three/LICENSE "$here/three-LICENSE"
echo "three $THREE_VERSION -> $here/three.min.js"
