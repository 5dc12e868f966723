#!/usr/bin/env bash
# The terminal figures of docs/guide.md's "Images in the terminal":
#  1. probe time per terminal (13 played on a pty, real tmux 3.3a, real xterm
#     -ti vt340 under Xvfb), from tests/terminals.rs's own report;
#  2. bytes and times per frame per protocol, at rest and moving (tui_latency);
#  3. over a real pty, unthrottled and at 10 Mbit/s: moving and full frame
#     bytes, first key -> frame, last key -> full frame (term_link), ROUNDS times.
# Usage: ROUNDS=3 POINTS=2000000 bash bench/terminal.sh
set -euo pipefail
cd "$(dirname "$0")/.."
ROUNDS=${ROUNDS:-3}
POINTS=${POINTS:-2000000}
export NODEVICE_SELECT=1
cargo build --release --bins --example tui_latency --example term_link 2>&1 | tail -1
echo "== probe times (uptime: $(uptime | sed 's/.*load/load/'))"
cargo test --test terminals -- --nocapture --test-threads 1 2>&1 \
  | grep -E "probe|tmux with|xterm -ti" | sed 's/^test [a-z_]* \.\.\. //'
echo "== frames per protocol (tui_latency $POINTS points, 8 presses, cpu)"
target/release/examples/tui_latency "$POINTS" 8 cpu
for r in $(seq "$ROUNDS"); do
  echo "== over a pty, round $r"
  target/release/examples/term_link "$POINTS" 0 10
done
