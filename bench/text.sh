#!/usr/bin/env bash
# Text-mode quality: our symbol encoder against chafa on the same frames.
#
#   bash bench/text.sh [PCIMG_BIN]
#
# Renders three datasets (fixtures: an airborne scan in colour seen from above
# and obliquely, a lamppost's thin structure, a building in colour) to
# 960×640 PNGs, i.e. 120×40 cells of 8×16 pixels, then runs
# crates/term/examples/text_quality.rs on each: SSIM against the frame and bytes
# for half blocks, quadrants, sextants, octants and braille, ours and chafa's
# (chafa 1.12: `apt-get install chafa`; --work 9, its best), in 24-bit, 256 and
# 16 colours, and our encode time per frame. In 256 and 16 colours, also ours
# undithered (--no-dither: the nearest palette colours) and chafa with its
# diffusion dither (its default is none). Each line also gives the colour error
# from afar ("far": both pictures averaged over two cells, mean RGB distance).
set -euo pipefail
cd "$(dirname "$0")/.."
bin=${1:-target/release/pcimg}
command -v chafa >/dev/null || { echo "bench/text.sh: chafa is not installed (apt-get install chafa)" >&2; exit 1; }
[ -x "$bin" ] || cargo build --release -q
cargo build --release -q -p pcimg-term --example text_quality
q=target/release/examples/text_quality
dir=${TMPDIR:-/tmp}/pcimg-bench/text
mkdir -p "$dir"
chafa --version | head -1
frame() { # NAME INPUT [render options...]
  local name=$1 input=$2
  shift 2
  [ -d "$dir/$name.pcimg" ] || "$bin" convert "$input" -o "$dir/$name.pcimg" -q
  "$bin" render "$dir/$name.pcimg" -o "$dir/$name.png" --width 960 --height 640 "$@" >/dev/null
}
frame autzen-top fixtures/autzen_trim.laz --view 0,-89
frame autzen-oblique fixtures/autzen_trim.laz --view 30,-35
frame lamppost fixtures/lamppost.pcd
frame building fixtures/cgal_b9_training.ply --view 30,-30
for f in autzen-top autzen-oblique lamppost building; do
  for c in full 256 16; do
    echo
    "$q" "$dir/$f.png" 120 40 --colors "$c" --runs 15
    if [ "$c" != full ]; then
      echo
      "$q" "$dir/$f.png" 120 40 --colors "$c" --runs 3 --no-dither
      echo
      "$q" "$dir/$f.png" 120 40 --colors "$c" --runs 3 --dither diffusion
    fi
  done
done
