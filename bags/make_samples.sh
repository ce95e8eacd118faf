#!/usr/bin/env bash
# Regenerates the sample recordings in bags/ with the project's own tools (sim_node's recorder, via the demo).
# Real-time factor 1, so log time follows simulated time as on a robot. DDS stays on this machine.
set -euo pipefail
cd "$(dirname "$0")/.."
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
FLAGBOT="${FLAGBOT:-.venv/bin/flagbot}"
OUT="$(mktemp -d)"            # recorded there first: a failed run leaves the committed samples as they were
trap 'rm -rf "$OUT"' EXIT
run() { "$FLAGBOT" demo --real-time-factor 1.0 --json "$@" > /dev/null; }
run --scene design1 --n 2 --rpm 50,100,150 --step-duration 12 --record $OUT/design1_n2_steps.mcap
run --scene design1 --n 3 --rpm 100,150 --step-duration 12 --record $OUT/design1_n3_steps.mcap
run --scene design2 --n 2 --rpm 50,100 --step-duration 8 --record $OUT/design2_n2_steps.mcap
run --scene design2 --n 3 --rpm 50,100 --step-duration 8 --record $OUT/design2_n3_steps.mcap
# a command reversal and a pass through zero (the motor turns back: a command, not a reset, for --resimulate)
run --scene design2 --n 2 --rpm=50,-50,0,50 --step-duration 8 --record $OUT/design2_n2_reversal.mcap
for f in "$OUT"/*.mcap; do "$FLAGBOT" replay --resimulate "$f" > /dev/null || { echo "not reproduced: $f" >&2; exit 1; }; done
mv "$OUT"/*.mcap bags/
ls -la bags/*.mcap
