#!/usr/bin/env bash
# Encode then decode the example lego scene (fitted by tools/fit_scene.py), printing both summaries.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="${1:-$(mktemp -d)}"
mkdir -p "$out"
gspc info "$here/lego/point_cloud.ply"
gspc encode "$here/lego/point_cloud.ply" --cameras "$here/lego/cameras.json" --background 1 1 1 -o "$out/lego.gspc"
gspc info "$out/lego.gspc"
gspc decode "$out/lego.gspc" -o "$out/lego_decoded.ply"
gspc eval "$here/lego/point_cloud.ply" "$out/lego_decoded.ply" --cameras "$here/lego/cameras.json" --background 1 1 1
echo "outputs in $out"
