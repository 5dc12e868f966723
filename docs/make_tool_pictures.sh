#!/usr/bin/env bash
# The viewer tools' pictures (issue 29) in docs/pictures/: classes and their
# legend, a class filter, a band through a ramp, a --where range, a clip seen
# from the side, eye-dome lighting strength, a turntable. CPU rasterizer.
#   bash docs/make_tool_pictures.sh [PCIMG]   (default: target/release/pcimg)
set -euo pipefail
P=${1:-target/release/pcimg}
OUT=docs/pictures
W=$(mktemp -d)
trap 'rm -rf "$W"' EXIT
"$P" convert -q fixtures/autzen_trim.laz -o "$W/autzen.tif"
"$P" synth -n 2000000 -o "$W/synth.las"
"$P" convert -q "$W/synth.las" -o "$W/synth.tif"
A=("$W/autzen.tif" --width 640 --height 360 --renderer cpu --view 200,-40,1050)
S=("$W/synth.tif" --width 640 --height 360 --renderer cpu --view 30,-35,500)
"$P" render "${A[@]}" --color classification --legend -o $OUT/tools-autzen-classes.png
"$P" render "${A[@]}" --color band:gps_time --ramp viridis --legend -o $OUT/tools-autzen-gps-time.png
"$P" render "${S[@]}" --color classification --legend -o $OUT/tools-synth-classes.png
"$P" render "${S[@]}" --color classification --exclude-classes 2 --legend -o $OUT/tools-synth-no-ground.png
"$P" render "${S[@]}" --color height --ramp turbo --where z=25..60 --legend -o $OUT/tools-synth-where-z.png
# A slab 4 m thick across x through a row of buildings, 240 m long, seen from the side (looking along +x).
"$P" render "$W/synth.tif" --width 640 --height 360 --renderer cpu --view 0,0,170 \
  --clip 637218,6010980,0,637222,6011220,100 --color classification --legend --point-size 2 \
  -o $OUT/tools-synth-section.png
"$P" render "${S[@]}" --color height --edl -o $OUT/tools-synth-edl-1.png
"$P" render "${S[@]}" --color height --edl-strength 2 --edl-radius 2 -o $OUT/tools-synth-edl-2r2.png
"$P" render "$W/synth.tif" --width 320 --height 180 --renderer cpu --view 30,-35,520 \
  --color classification --turntable 24 -o $OUT/tools-synth-turntable.png
