#!/usr/bin/env bash
# Renders every technique and part combination at 64² for a few frames and prints a SHA-256
# of each linear EXR: run it before and after a refactor that must not change any image
# (issue 56), then `diff` the two lists.   tools/bit-identical.sh > before.txt
# GILAB picks the binary, GILAB_SHADERS the shader folder (an old tree's, for the "before"),
# SCENES the scenes, ONLY a regex over "scene technique|params" lines.
set -euo pipefail
cd "$(dirname "$0")/.."
gilab=${GILAB:-target/release/gilab}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
combos=(
  "reference|"
  "restir|"
  "restir|gi_terminate=\"lumen-cards\""
  "restir|gi_terminate=\"lumen-world\""
  "restir|gi_terminate=\"surfels\""
  "restir-pt|"
  "restir-pt|direct=\"restir\""
  "surfels|"
  "surfels|direct=\"restir\""
  "surfels|cache_direct=\"regir\""
  "lumen|"
  "lumen|tracing=\"bvh\""
  "lumen|direct=\"restir\""
  "lumen|cache_direct=\"regir\""
  "callisto-shadows|"
  "callisto-shadows|direct=\"restir\""
  "callisto-shadows|gi=true"
  "callisto-shadows|gi=true|gi_terminate=\"lumen-cards\""
  "callisto-shadows|gi=true|gi_terminate=\"surfels\""
)
for scene in ${SCENES:-cornell glossy many-lights}; do
  for combo in "${combos[@]}"; do
    [[ "$scene $combo" =~ ${ONLY:-.} ]] || continue
    IFS='|' read -r -a parts <<<"$combo"
    tech=${parts[0]}
    sets=()
    for kv in "${parts[@]:1}"; do [ -n "$kv" ] && sets+=(--set "$kv"); done
    name="$scene ${combo}"
    dir="$out/$(echo "$name" | tr -c 'a-zA-Z0-9' _)"
    "$gilab" shot --scene "$scene" --technique "$tech" --size 64 --spp 4 --seed 1 \
      "${sets[@]}" --out "$dir" >/dev/null 2>&1 || { echo "FAILED $name"; continue; }
    exr=$(find "$dir" -name '*.exr' | head -1)
    echo "$(sha256sum "$exr" | cut -c1-16) $name"
  done
done
