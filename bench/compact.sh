#!/usr/bin/env bash
# Compact storage (issue 40): bytes a point, pyramid and index included, per codec
# and per band for the default, next to the LAZ (and the COPC where one is given);
# then conversion time of the default against `--compression none`, interleaved
# run by run, and the read speed of x y z from the page cache for both.
#
#   bash bench/compact.sh [PCIMG_BINARY] [INPUT] [REPS] [COPC]
#   (defaults: target/release/pcimg, fixtures/autzen_trim.laz, 3, none)
#
# The 47.7 M-point figures: INPUT=/tmp/pcimg-bench/autzen-tiled-47756566.las
# (made by bench/autzen_tiled.py). The LAZ of an uncompressed LAS input is
# written by laspy (with lazrs) for the comparison. Read speed is
# `cargo run --release --example read_speed` (built here first).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
source "$here/lib.sh"
BIN=${1:-target/release/pcimg}
INPUT=${2:-fixtures/autzen_trim.laz}
REPS=${3:-3}
COPC=${4:-}
cargo build --release -q --example read_speed
READ=target/release/examples/read_speed
scratch_dir pcimg-compact
laz=$INPUT
case $INPUT in
  *.las|*.LAS)
    laz=$DIR/input.laz
    /usr/bin/python3 -c "import laspy,sys; laspy.read(sys.argv[1]).write(sys.argv[2])" "$INPUT" "$laz"
    ;;
esac
lazb=$(stat -c %s "$laz")
"$BIN" convert "$INPUT" -o "$DIR/zstd" -q
points=$("$BIN" info --json "$DIR/zstd" | python3 -c "import json,sys; print(json.load(sys.stdin)['points'])")
row() { awk -v n="$1" -v b="$2" -v p="$points" -v l="$lazb" \
  'BEGIN { printf "%-40s %12.0f bytes  %6.2f B/point  %5.2f x LAZ\n", n, b, b / p, b / l }'; }
echo "input: $INPUT, $points points; $(date -u +%FT%TZ), $(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg)"
row "LAZ" "$lazb"
[ -n "$COPC" ] && row "COPC ($(basename "$COPC"))" "$(stat -c %s "$COPC")"
row "pcimg default (zstd, format 2)" "$(du -sb "$DIR/zstd" | cut -f1)"
for c in none deflate lerc_zstd; do
  "$BIN" convert "$INPUT" -o "$DIR/$c" -q --compression "$c"
  row "pcimg --compression $c" "$(du -sb "$DIR/$c" | cut -f1)"
done
echo "default, bytes a point per band (every part and overview node, every level):"
python3 - "$DIR/zstd" "$points" <<'PY'
import glob, os, struct, sys
root, n = sys.argv[1], int(sys.argv[2])
tot, names = {}, None
for path in sorted(glob.glob(os.path.join(root, "**", "*.tif"), recursive=True)):
    d = open(path, "rb").read()
    big = struct.unpack("<H", d[2:4])[0] == 43
    off = struct.unpack("<Q" if big else "<I", d[8:16] if big else d[4:8])[0]
    while off:
        if big:
            cnt = struct.unpack("<Q", d[off:off + 8])[0]; ent, at = 20, off + 8
        else:
            cnt = struct.unpack("<H", d[off:off + 2])[0]; ent, at = 12, off + 2
        tags = {}
        for i in range(cnt):
            e = d[at + ent * i: at + ent * (i + 1)]
            if big:
                t, ty, c = struct.unpack("<HHQ", e[:12]); v = e[12:20]
            else:
                t, ty, c = struct.unpack("<HHI", e[:8]); v = e[8:12]
            tags[t] = (ty, c, v)
        ty, c, v = tags[325]
        size = {3: 2, 4: 4, 16: 8}[ty]
        fmt = {2: "H", 4: "I", 8: "Q"}[size]
        raw = v if c * size <= len(v) else d[struct.unpack("<Q" if big else "<I", v)[0]:][:c * size]
        counts = struct.unpack("<%d%s" % (c, fmt), raw[:c * size])
        spp = struct.unpack("<H", tags[277][2][:2])[0]
        per = c // spp
        for b in range(spp):
            tot[b] = tot.get(b, 0) + sum(counts[b * per:(b + 1) * per])
        if names is None and 42112 in tags:
            import re
            ty, c, v = tags[42112]
            xml = d[struct.unpack("<Q" if big else "<I", v)[0]:][:c].decode("latin1")
            m = re.search(r'name="BANDS">([^<]*)<', xml)
            names = m.group(1).split() if m else None
        off = struct.unpack("<Q" if big else "<I", d[at + ent * cnt: at + ent * cnt + (8 if big else 4)])[0]
names = names or [str(b + 1) for b in tot]
print("  " + "  ".join("%s %.2f" % (names[b], v / n) for b, v in sorted(tot.items())),
      " tiles %.2f, the rest (heads, index) %.2f" % (sum(tot.values()) / n,
      sum(os.path.getsize(p) for p in glob.glob(os.path.join(root, "**", "*"), recursive=True) if os.path.isfile(p)) / n - sum(tot.values()) / n))
PY
echo "conversion, $REPS runs each, interleaved (default | none):"
log=$DIR/convert.log
for r in $(seq "$REPS"); do
  run_convert zstd "$log" "$DIR" "$BIN" "$INPUT" >/dev/null
  run_convert none "$log" "$DIR" "$BIN" "$INPUT" --compression none >/dev/null
done
for l in zstd none; do
  printf '  %-5s wall %s s\n' "$l" "$(awk -v l=$l '$1 == l { print $3 }' "$log" | stats)"
done
awk '$1 == "zstd" { z[++i] = $3 } $1 == "none" { n[++j] = $3 } END { for (k = 1; k <= i; k++) print n[k] / z[k] }' "$log" |
  { printf '  speed of the default / none, run by run: '; stats; echo; }
echo "read x y z of level 0 from the page cache:"
for r in 1 2; do
  for c in zstd none deflate lerc_zstd; do "$READ" "$DIR/$c" --reps 7 | sed "s|$DIR/||; s|^|  |"; done
done
