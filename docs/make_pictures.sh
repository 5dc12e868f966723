#!/usr/bin/env bash
# Regenerates the pictures in docs/pictures/ that docs/pictures.md and the README
# show: the paper's Figures 5 and 6 for our data, rendered by `pcimg render`, and a
# screenshot of the inspector in a real terminal (xterm with sixel, under Xvfb).
#
#   bash docs/make_pictures.sh
#
# Needs: cargo; the sample scan fixtures/autzen_trim.laz (or PCIMG_DATA=DIR).
# For the screenshot only (skipped with a note when missing, never needed by CI):
#   apt-get install xvfb xterm x11-utils imagemagick
# All frames use the CPU rasterizer, so they do not depend on a GPU driver.
set -euo pipefail

cd "$(dirname "$0")/.."
OUT=docs/pictures
DATA=${PCIMG_DATA:-fixtures}
mkdir -p "$OUT"

cargo build --release --quiet
PCIMG=$PWD/target/release/pcimg
WORK=$(mktemp -d)
cleanup() {
    [ -n "${XTERM_PID:-}" ] && kill "$XTERM_PID" 2>/dev/null || true
    [ -n "${XVFB_PID:-}" ] && kill "$XVFB_PID" 2>/dev/null || true
    rm -rf "$WORK"
}
trap cleanup EXIT

render() { # DATASET OUTPUT [render options…]
    local ds=$1 out=$2
    shift 2
    echo "pcimg render $(basename "$ds") -o $out $*"
    "$PCIMG" render "$ds" -o "$OUT/$out" --width 640 --height 360 --renderer cpu "$@" 2>&1 |
        grep -v '^wrote'
}

# The data: a synthetic 4 M-point scan (4 levels: 4 M, 1 M, 250 k, 62.5 k points)
# and the real airborne scan of Autzen Stadium (110 k points: 2 levels).
"$PCIMG" synth -n 4000000 -o "$WORK/synth.xyz" >/dev/null
"$PCIMG" convert "$WORK/synth.xyz" -o "$WORK/synth.tif" -q
"$PCIMG" convert "$DATA/autzen_trim.laz" -o "$WORK/autzen.tif" -q

# Figure 5: the same view at every level of the pyramid.
for level in 0 1 2 3; do
    render "$WORK/synth.tif" "fig5-synth-level$level.png" --view 30,-35,500 --lod "$level" --color height
done
for level in 0 1; do
    render "$WORK/autzen.tif" "fig5-autzen-level$level.png" --view 200,-40,1050 --lod "$level" --color rgb
done

# Figure 6: the camera approaches; the paper's distance rule picks finer levels.
# Thresholds double from half the bounds' diagonal (574 m here): 287, 574, 1148 m.
for dist in 1600 900 450 220; do
    render "$WORK/synth.tif" "fig6-synth-$dist.png" --view 30,-35,"$dist" --lod distance --color height
done

# The inspector in xterm under Xvfb: sixel (256 colour registers), then
# half-blocks (what tmux and plain terminals get; without eye-dome lighting, which
# darkens every point at one pixel per half-cell).
screenshot() { # OUTPUT PROTOCOL [inspect options…]
    local out=$1 protocol=$2
    shift 2
    local display=:$((90 + RANDOM % 9))
    Xvfb "$display" -screen 0 1400x900x24 >/dev/null 2>&1 &
    XVFB_PID=$!
    sleep 1
    DISPLAY=$display xterm -ti vt340 -xrm 'XTerm*numColorRegisters: 256' \
        -xrm 'XTerm*maxGraphicSize: 2000x2000' -fa 'DejaVu Sans Mono' -fs 9 \
        -geometry 160x46+0+0 -e "$PCIMG" inspect "$WORK/autzen.tif" --protocol "$protocol" \
        --renderer cpu --view 200,-30,800 "$@" &
    XTERM_PID=$!
    sleep 8
    local window
    window=$(DISPLAY=$display xwininfo -root -tree | awk '/xterm/ {print $1; exit}')
    DISPLAY=$display import -window "$window" "$OUT/$out"
    echo "xterm -ti vt340 -e pcimg inspect autzen.tif --protocol $protocol --view 200,-30,800 $* -> $OUT/$out"
    kill "$XTERM_PID" "$XVFB_PID" 2>/dev/null || true
    wait "$XTERM_PID" "$XVFB_PID" 2>/dev/null || true
    XTERM_PID= XVFB_PID=
}
if command -v Xvfb >/dev/null && command -v xterm >/dev/null && command -v xwininfo >/dev/null &&
    command -v import >/dev/null; then
    screenshot inspector-sixel.png sixel --edl
    screenshot inspector-halfblocks.png halfblocks
else
    echo "no Xvfb/xterm/xwininfo/import: the inspector screenshots are left as they are" >&2
fi

du -ch "$OUT"/*.png | tail -1
