# Shared by the benchmark scripts (ab.sh, multi.sh, faults.sh, upload_faults.sh);
# sourced, not run.

# run_convert LABEL LOG OUTDIR BIN INPUT [options...]: one conversion into OUTDIR/out
# (removed first), timed by GNU time; prints "LABEL wall .. user .. sys .. peak .."
# and appends it to LOG.
run_convert() {
  local label=$1 log=$2 dir=$3 bin=$4 input=$5 wall user sys kib
  shift 5
  rm -rf "$dir/out"
  sync
  /usr/bin/time -f "%e %U %S %M" -o "$dir/t.txt" "$bin" convert "$input" -o "$dir/out" -q "$@"
  read -r wall user sys kib < "$dir/t.txt"
  printf '%-6s  wall %6.2f s  user %6.2f s  sys %6.2f s  peak %6.0f MiB\n' \
    "$label" "$wall" "$user" "$sys" "$((kib / 1024))" | tee -a "$log"
}

# median_wall LABEL LOG: the median wall time of LABEL's runs in LOG.
median_wall() {
  awk -v l="$1" '$1 == l { print $3 }' "$2" | sort -g |
    awk '{ v[NR] = $1 } END { print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2 }'
}

# stats: numbers on stdin as "median (min-max)".
stats() {
  sort -g | awk '{v[NR]=$1} END {m = (NR % 2) ? v[(NR+1)/2] : (v[NR/2] + v[NR/2+1]) / 2;
    printf "%.2f (%.2f-%.2f)", m, v[1], v[NR]}'
}

# scratch_dir PREFIX: sets DIR to a new temporary directory and PIDS to an
# empty list; on exit every process in PIDS (servers the script started) is
# killed and reaped, and DIR removed.
scratch_dir() {
  DIR=$(mktemp -d "/tmp/$1.XXXXXX")
  PIDS=()
  trap 'for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null || true; wait "$p" 2>/dev/null || true; done; rm -rf "$DIR"' EXIT
}
