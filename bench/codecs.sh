#!/usr/bin/env bash
# Bytes a point per codec next to LAZ, pyramid included: converts INPUT (LAS/LAZ)
# with each of pcimg's codecs (the LERC ones at their default bound: half the LAS
# scale for x y z, attributes lossless), then re-encodes the uncompressed part
# with GDAL's LERC for reference: every band at once at the part's
# MAX_QUANTIZATION_ERROR (pyramid included), and band by band with its own error
# bound (x y z at that bound, integer-valued bands at 0.5, lossless for integers,
# the others lossless): gdal_translate -b drops the overviews, so those rows are
# level 0 only.
#
#   bash bench/codecs.sh [PCIMG_BINARY] [INPUT]
#   (defaults: target/release/pcimg, fixtures/autzen_trim.laz)
#
# Needs gdal_translate and python3. Read speed per codec: `cargo bench --bench
# store -- read-xyz` (bench/RESULTS.md).
set -euo pipefail
BIN=${1:-target/release/pcimg}
INPUT=${2:-fixtures/autzen_trim.laz}
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT
laz=$(stat -c %s "$INPUT")
"$BIN" convert "$INPUT" -o "$OUT/none" -q --compression none
points=$("$BIN" info --json "$OUT/none" | python3 -c "import json,sys; print(json.load(sys.stdin)['points'])")
row() { awk -v n="$1" -v b="$2" -v p="$points" -v l="$laz" \
  'BEGIN { printf "%-34s %10d bytes  %6.2f B/point  %5.2f x input\n", n, b, b / p, b / l }'; }
echo "input: $INPUT, $points points"
row "input ($(basename "$INPUT"))" "$laz"
for c in none deflate zstd lerc lerc_deflate lerc_zstd; do
  [ -d "$OUT/$c" ] || "$BIN" convert "$INPUT" -o "$OUT/$c" -q --compression "$c"
  row "pcimg --compression $c" "$(du -sb "$OUT/$c" | cut -f1)"
done
part=$(ls "$OUT"/none/*.tif | head -1)
[ "$(ls "$OUT"/none/*.tif | wc -l)" -eq 1 ] || { echo "LERC reference: one part expected"; exit 0; }
err=$(gdalinfo "$part" | sed -n 's/.*MAX_QUANTIZATION_ERROR=//p')
names=$(gdalinfo "$part" | sed -n 's/.*Description = //p')
tiled=(-co INTERLEAVE=BAND -co TILED=YES -co BLOCKXSIZE=256 -co BLOCKYSIZE=256 -co COPY_SRC_OVERVIEWS=YES)
for codec in LERC_ZSTD LERC_DEFLATE; do
  rm -f "$OUT/all.tif"
  gdal_translate -q "${tiled[@]}" -co COMPRESS="$codec" -co MAX_Z_ERROR="$err" \
    "$part" "$OUT/all.tif"
  row "GDAL $codec, all bands at $err" "$(stat -c %s "$OUT/all.tif")"
done
for codec in LERC_ZSTD LERC_DEFLATE; do
  total=0 b=0
  for name in $names; do
    b=$((b + 1))
    case $name in
      x|y|z) e=$err ;;
      intensity|return_number|number_of_returns|classification|red|green|blue|\
      point_source_id|user_data|scan_angle_rank|nir) e=0.5 ;;
      *) e=0 ;;
    esac
    rm -f "$OUT/b.tif"
    gdal_translate -q -b "$b" "${tiled[@]}" -co COMPRESS="$codec" -co MAX_Z_ERROR="$e" \
      "$part" "$OUT/b.tif" 2>/dev/null
    total=$((total + $(stat -c %s "$OUT/b.tif")))
  done
  row "GDAL $codec, per-band, level 0 only" "$total"
done
