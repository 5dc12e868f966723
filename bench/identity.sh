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
# fixed size, each saved with `s` as PNG once the view is idle (every tile
# loaded, no frame pending).
if command -v tmux >/dev/null; then
  S=pcimg-identity-$$
  SOCK=$W/tmux.sock
  mkdir -p "$W/insp"
  screen() { tmux -S "$SOCK" capture-pane -p -t "$S" 2>/dev/null; }
  # wait_for PATTERN: up to 30 s for the screen to show PATTERN.
  wait_for() {
    for _ in $(seq 120); do screen | grep -q -- "$1" && return 0; sleep 0.25; done
    return 1
  }
  inspect_frames() {
    local name=$1 data=$2 n=0 keys f
    tmux -S "$SOCK" kill-server 2>/dev/null || true
    rm -f "$W/insp"/*.png
    tmux -S "$SOCK" -f /dev/null new-session -d -s "$S" -x 120 -y 36 \
      "cd '$W/insp' && NODEVICE_SELECT=1 '$BIN' inspect '$data' --renderer cpu --protocol halfblocks; sleep 60"
    wait_for "levels of" || { echo "${name} FAILED (no inspector)"; return; }
    for keys in "" c c l; do
      [ -n "$keys" ] && tmux -S "$SOCK" send-keys -t "$S" "$keys" && sleep 1
      wait_for " idle" || true
      tmux -S "$SOCK" send-keys -t "$S" s
      # Saved as pcimg-frame-NNN.png, numbered from 1; complete when its size
      # holds still.
      f=$(printf '%s/insp/pcimg-frame-%03d.png' "$W" "$((n + 1))")
      local size=-1 now
      for _ in $(seq 120); do
        now=$(stat -c %s "$f" 2>/dev/null || echo -1)
        [ "$now" -gt 0 ] && [ "$now" = "$size" ] && break
        size=$now
        sleep 0.25
      done
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
