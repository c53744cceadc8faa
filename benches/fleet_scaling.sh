#!/usr/bin/env bash
# Robots on one ground at size: `tensegrity generate sixbar --robots N` for N in 1 5 10 25 50 100
# (6 N bodies, 12 N contact spheres, 24 N cables), the time `statics` takes (median of 5 runs,
# model building and the stability test included) and its Newton iterations, and the cost of a
# generalized-alpha step at 1 ms over the roll (median of `bench steps --steps 500`), per robot.
# Writes a Markdown table to standard output (docs/benchmarks.md, "Robots on one ground").
#
#   cargo build --release && bash benches/fleet_scaling.sh [ROBOTS...]
set -euo pipefail
cd "$(dirname "$0")/.."
bin=target/release/tensegrity
robots=("$@")
[ ${#robots[@]} -gt 0 ] || robots=(1 5 10 25 50 100)
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
median() { sort -g | awk '{a[NR] = $1} END {print (NR % 2) ? a[(NR + 1) / 2] : (a[NR / 2] + a[NR / 2 + 1]) / 2}'; }
echo "| robots | bodies | coordinates | contact spheres | statics, s | Newton iterations | step, us | step per robot, us |"
echo "| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"
for n in "${robots[@]}"; do
  scene="$dir/fleet$n.toml"
  "$bin" generate sixbar --robots "$n" --out "$scene"
  for _ in 1 2 3 4 5; do
    start=$(date +%s.%N)
    "$bin" statics "$scene" > "$dir/statics.txt"
    end=$(date +%s.%N)
    echo "$end - $start" | bc -l
  done | median > "$dir/t"
  iterations=$(sed -n '1s/.*after \([0-9]*\) Newton.*/\1/p' "$dir/statics.txt")
  coordinates=$("$bin" check "$scene" | sed -n 's/^coordinates: //p')
  step=$("$bin" bench steps "$scene" --steps 500 | sed -n 's/.*median \([0-9.]*\) us\/step.*/\1/p')
  printf '| %d | %d | %d | %d | %.3f | %s | %s | %.1f |\n' "$n" $((6 * n)) "$coordinates" $((12 * n)) \
    "$(cat "$dir/t")" "$iterations" "$step" "$(echo "$step / $n" | bc -l)"
done
