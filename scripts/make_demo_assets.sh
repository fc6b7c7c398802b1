#!/bin/bash
# Writes the generated assets of scenes/smoke.json (not committed: about 40 MB) with the project's own
# generators: a smoke cloud drifting 0.05 units a frame along +x over frames 0..23, with the velocity that
# moves it (float grids vel.x/y/z, world units per second at 24 fps), and a clear sky whose low sun is the
# scene's only direct light. Rewrites them each time (a few seconds).
#
#   scripts/make_demo_assets.sh [OUT_DIR]     (default scenes/assets; HAZE=path/to/haze, default build/haze)
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
haze=${HAZE:-$root/build/haze}
out=${1:-$root/scenes/assets}
if [ ! -x "$haze" ]; then
  echo "make_demo_assets.sh: no haze binary at $haze: build first (make build) or set HAZE" >&2
  exit 1
fi
mkdir -p "$out"
"$haze" vdb make cloud --out "$out/smoke_####.vdb" --frames 0:23 --move 0.05 0 0 --velocity --fps 24 \
  --voxel-size 0.04 --center 0 0 0 --size 2.2 2.2 2.2 --density 3 --falloff 0.6 --frequency 1.6 --seed 11 \
  --octaves 4
"$haze" envmap make --out "$out/sky.exr" --width 1024 --height 512 --sun-elevation 27 --sun-azimuth -19 \
  --sun-size 2 --sun-radiance 20000
