#!/usr/bin/env bash
# The dataset hierarchy (issue 26): for datasets of many parts and a single-part
# dataset of the same points, the time to open the dataset and draw the first frame
# of the whole of it (`pcimg render --view 0,-89`, CPU rasterizer, 1280x720), page
# cache warm and cold; the points loaded, the bytes read from the disk (cold), and
# the tiles given up; and the share of the conversion spent on the index and
# overview.
#
#   bash bench/hierarchy.sh                        # about 8, 144 and 1,000 parts
#   SIZES="1200000:64MiB" bash bench/hierarchy.sh   # one dataset: points:--memory
#
# Cold runs drop the page cache (`echo 3 > /proc/sys/vm/drop_caches`): run as root.
# `--memory 256MiB` makes parts of up to 1.6 M synthetic LAS points (4-5 levels),
# `--memory 64MiB` parts of up to 140,000 (2 levels). PREP=1 only makes the data.
set -euo pipefail
cd "$(dirname "$0")/.."
DIR=${DIR:-/tmp/pcimg-hier}
BIN=$PWD/target/release/pcimg
SIZES=${SIZES:-"12000000:256MiB 13000000:64MiB 92000000:64MiB"}
REPS=${REPS:-5}
cargo build --release -q
mkdir -p "$DIR"
echo "machine: $(nproc) cores, $(free -g | awk '/Mem:/ {print $2}') GiB, $(uname -sr); $(date -u +%FT%TZ)"

drop() { sync; echo 3 > /proc/sys/vm/drop_caches; }

# pair MANY ONE LABEL MODE: REPS first frames of each dataset, interleaved (many,
# one, many, ...); per dataset the median wall time in ms (range), the points,
# tiles and given-up tiles of the last frame, and (cold) the median bytes read.
pair() {
  local many=$1 one=$2 label=$3 mode=$4
  declare -A walls reads line
  for _ in $(seq "$REPS"); do
    for ds in "$many" "$one"; do
      [ "$mode" = cold ] && drop
      local t0 t1
      t0=$(date +%s%N)
      /usr/bin/time -f "%I" -o "$DIR/t.txt" "$BIN" render "$ds" -o "$DIR/f.png" \
        --view 0,-89 --renderer cpu 2> "$DIR/err.txt" || { cat "$DIR/err.txt"; exit 1; }
      t1=$(date +%s%N)
      walls[$ds]+="$(( (t1 - t0) / 1000 )) "
      reads[$ds]+="$(( $(cat "$DIR/t.txt") * 512 )) "
      line[$ds]=$(grep ' points from ' "$DIR/err.txt" | tail -1)
    done
  done
  local med_many=""
  for ds in "$many" "$one"; do
    local name med lo hi rd pts tiles gave
    [ "$ds" = "$many" ] && name="$label" || name="1 part"
    read -r med lo hi < <(tr ' ' '\n' <<< "${walls[$ds]}" | grep . | sort -g |
      awk '{v[NR]=$1} END {printf "%.1f %.1f %.1f\n", v[int((NR+1)/2)]/1000, v[1]/1000, v[NR]/1000}')
    rd=$(tr ' ' '\n' <<< "${reads[$ds]}" | grep . | sort -g | awk '{v[NR]=$1} END {printf "%.1f", v[int((NR+1)/2)]/1e6}')
    pts=$(sed -E 's/^([0-9,]+) points.*/\1/' <<< "${line[$ds]}")
    tiles=$(sed -E 's/^[0-9,]+ points from ([0-9]+) tiles.*/\1/' <<< "${line[$ds]}")
    gave=$(grep -oE 'gave up loading [0-9]+' <<< "${line[$ds]}" | grep -oE '[0-9]+$' || echo 0)
    printf '%-12s %-5s %7.1f ms (%s-%s)  points %11s  tiles %4s  given up %s  read %6s MB' \
      "$name" "$mode" "$med" "$lo" "$hi" "$pts" "$tiles" "$gave" "$rd"
    if [ -z "$med_many" ]; then
      med_many=$med
      echo
    else
      awk -v a="$med_many" -v b="$med" 'BEGIN {printf "   many/one %.2f\n", a / b}'
    fi
  done
}

for spec in $SIZES; do
  n=${spec%%:*}
  mem=${spec##*:}
  in="$DIR/scan-$n.las"
  [ -f "$in" ] || "$BIN" synth -n "$n" --order scan -o "$in" > /dev/null
  many="$DIR/many-$n-$mem.pcimg"
  one="$DIR/one-$n.tif"
  if [ ! -f "$many/pcimg-index.json" ]; then
    rm -rf "$many"
    "$BIN" convert "$in" -o "$many" --memory "$mem" --timings -q > "$DIR/conv-$n-$mem.txt"
  fi
  [ -f "$one" ] || "$BIN" convert "$in" -o "$one" --memory 16G -q
  [ -n "${PREP:-}" ] && continue
  parts=$(ls "$many"/*.tif | wc -l)
  echo
  echo "== $n points: $parts parts (--memory $mem) against one part"
  # The conversion again, timed on its own (the data prep may have run beside
  # other work).
  rm -rf "$many"
  "$BIN" convert "$in" -o "$many" --memory "$mem" --timings -q > "$DIR/conv-$n-$mem.txt"
  grep -E 'part\(s\)|indexed|M points/s|index and overview' "$DIR/conv-$n-$mem.txt" | sed 's/^ */  /' 
  pair "$many" "$one" "$parts parts" warm
  pair "$many" "$one" "$parts parts" cold
  # The overview rebuilt alone (pcimg index), for parts made separately.
  /usr/bin/time -f "%e" -o "$DIR/t.txt" "$BIN" index "$many" -q
  echo "  pcimg index alone: $(cat "$DIR/t.txt") s"
done
