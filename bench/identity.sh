#!/usr/bin/env bash
# Hashes of what a pcimg binary writes: conversions of every fixture format and
# codec, several parts, the paper's layout; frames in every colour mode, with the
# legend, a pick, filters, EDL and a turntable. Two builds agree when their
# outputs' lists are identical (`diff`): the check that moving code changed
# nothing.
#
#   bash bench/identity.sh target/release/pcimg > after.txt
#   bash bench/identity.sh /path/to/old/pcimg > before.txt && diff before.txt after.txt
set -euo pipefail
BIN=$(realpath "$1")
ROOT=$(cd "$(dirname "$0")/.." && pwd)
F=$ROOT/fixtures
W=$(mktemp -d)
trap 'rm -rf "$W"' EXIT
export NODEVICE_SELECT=1
# Every file of a dataset, in name order (parts, index, overview).
hash_out() {
  local name=$1 path=$2
  if [ -d "$path" ]; then
    (cd "$path" && find . -type f | LC_ALL=C sort | while read -r f; do
      case "$f" in
        # The index records each part's mtime: hashed with the mtimes blanked.
        *pcimg-index.json) h=$(sed -E 's/"mtime": *\[[^]]*\]/"mtime":0/g' "$f" | sha256sum) ;;
        *) h=$(sha256sum < "$f") ;;
      esac
      echo "$name $f ${h%% *}"
    done)
  else
    echo "$name $(sha256sum < "$path" | cut -d' ' -f1)"
  fi
}
conv() {
  local name=$1; shift
  "$BIN" convert "$@" -o "$W/$name.pcimg" >/dev/null 2>&1 || { echo "$name FAILED"; return; }
  hash_out "$name" "$W/$name.pcimg"
}
conv laz "$F/autzen_trim.laz"
conv ply "$F/bun_zipper.ply"
conv ply_training "$F/cgal_b9_training.ply"
conv pcd "$F/lamppost.pcd"
conv pcd_milk "$F/milk.pcd"
conv e57 "$F/bunnyFloat.e57"
conv e57_int "$F/bunnyInt21.e57"
for c in none deflate zstd lerc lerc_deflate lerc_zstd; do
  conv "laz_$c" "$F/autzen_trim.laz" --compression "$c"
done
"$BIN" synth -n 1500000 -o "$W/s.las" >/dev/null 2>&1
hash_out synth_las "$W/s.las"
conv synth_parts "$W/s.las" --memory 64MiB
conv synth_parts_zstd "$W/s.las" --memory 64MiB --compression zstd
conv laz_paper "$F/autzen_trim.laz" --layout paper
D=$W/laz.pcimg
render() {
  local name=$1; shift
  "$BIN" render "$D" -o "$W/$name.png" --width 320 --height 200 --renderer cpu "$@" \
    > "$W/$name.out" 2>/dev/null || { echo "$name FAILED"; return; }
  hash_out "$name" "$W/$name.png"
  [ -s "$W/$name.out" ] && echo "$name stdout $(sed "s|$W|W|g" "$W/$name.out")"
  return 0
}
for c in rgb height intensity classification band:gps_time band:return_number; do
  render "frame_$c" --color "$c"
done
render frame_legend_class --color classification --legend
render frame_legend_ramp --color intensity --legend --range 0,200
render frame_pick --pick 160,100
render frame_classes --classes 2 --color classification
render frame_clip --clip 637200,851000,0,638000,852000,1000
render frame_where --where 'intensity=10..100'
render frame_edl --edl
render frame_points --point-size 2
render frame_lod --lod 0
"$BIN" render "$D" -o "$W/turn.png" --width 160 --height 100 --renderer cpu --turntable 4 \
  >/dev/null 2>&1 && hash_out turntable "$W/turn.png" || echo "turntable FAILED"
D=$W/synth_parts.pcimg
render frame_parts
render frame_parts_legend --color height --legend
render frame_parts_pick --pick 100,80 --color intensity
# The inspector's frames (the same pipeline, driven by keys): in a tmux of a
# fixed size, each saved with `s` as PNG; tiles settle before each save.
if command -v tmux >/dev/null; then
  S=pcimg-identity-$$
  SOCK=$W/tmux.sock
  mkdir -p "$W/insp"
  inspect_frames() {
    local name=$1 data=$2; shift 2
    tmux -S "$SOCK" kill-server 2>/dev/null || true
    rm -f "$W/insp"/*.png
    tmux -S "$SOCK" -f /dev/null new-session -d -s "$S" -x 120 -y 36 \
      "cd '$W/insp' && NODEVICE_SELECT=1 '$BIN' inspect '$data' --renderer cpu --protocol halfblocks $*; sleep 60"
    local n=0
    for keys in "" c c l; do
      [ -n "$keys" ] && tmux -S "$SOCK" send-keys -t "$S" "$keys"
      # Settled: the screen the same twice, half a second apart.
      local prev="" now
      for _ in $(seq 40); do
        sleep 0.5
        now=$(tmux -S "$SOCK" capture-pane -p -t "$S")
        [ "$now" = "$prev" ] && break
        prev=$now
      done
      tmux -S "$SOCK" send-keys -t "$S" s
      local f
      f=$(printf '%s/insp/pcimg-frame-%03d.png' "$W" "$n")
      for _ in $(seq 40); do [ -s "$f" ] && break; sleep 0.25; done
      sleep 0.3
      if [ -s "$f" ]; then hash_out "${name}_$n${keys:+_$keys}" "$f"; else echo "${name}_$n FAILED"; fi
      n=$((n + 1))
    done
    tmux -S "$SOCK" kill-server 2>/dev/null || true
  }
  inspect_frames inspect "$W/laz.pcimg"
  inspect_frames inspect_parts "$W/synth_parts.pcimg"
else
  echo "inspector frames SKIPPED (no tmux)"
fi
