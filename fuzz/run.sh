#!/usr/bin/env bash
# Runs one fuzz target for SECONDS (cargo-fuzz, nightly) and prints one summary line:
#   TARGET: N execs in S s (E exec/s), corpus C, crashes K
set -euo pipefail
target=$1
seconds=${2:-600}
cd "$(dirname "$0")"
log=$(mktemp)
status=0
timeout $((seconds + 300)) cargo +nightly fuzz run -O "$target" -- -max_total_time="$seconds" -print_final_stats=1 >"$log" 2>&1 || status=$?
done_line=$(grep -E '^#[0-9]+[[:space:]]+DONE' "$log" | tail -1 || true)
execs=$(grep -oE 'stat::number_of_executed_units: *[0-9]+' "$log" | grep -oE '[0-9]+$' || echo 0)
rate=$(grep -oE 'exec/s: *[0-9]+' <<<"$done_line" | grep -oE '[0-9]+$' || echo 0)
crashes=$(ls artifacts/"$target" 2>/dev/null | grep -c '^crash-' || true)
echo "$target: $execs execs in ${seconds} s ($rate exec/s), corpus $(ls corpus/"$target" | wc -l) files, crashes $crashes (exit $status)"
if [ "$status" -ne 0 ]; then tail -40 "$log"; fi
rm -f "$log"
[ "$status" -eq 0 ]
