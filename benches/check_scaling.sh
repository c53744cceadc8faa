#!/usr/bin/env bash
# Wall time of `tensegrity check` (parse, validate, form finding), `tensegrity statics` (the
# equilibrium and its stability test) and `tensegrity deploy --quasi-static` (40 load steps of the
# ring winch) on generated clustered n-prisms: median of 5 runs per size (3 for deploy), in
# seconds (ms resolution). Usage: bash benches/check_scaling.sh [N ...]
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -q
bin=target/release/tensegrity
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
sizes=("$@")
[ ${#sizes[@]} -gt 0 ] || sizes=(120 240 400 999)

# median wall time in microseconds of RUNS runs of the command
median_us() {
  local runs=$1
  shift
  local times=()
  for _ in $(seq "$runs"); do
    local s e
    s=$(date +%s%N)
    "$@" >/dev/null
    e=$(date +%s%N)
    times+=("$(((e - s) / 1000))")
  done
  printf '%s\n' "${times[@]}" | sort -g | sed -n "$(((runs + 1) / 2))p"
}
seconds() { printf '%d.%03d' "$(($1 / 1000000))" "$((($1 / 1000) % 1000))"; }

echo "| struts | coordinates | check s | statics s | deploy --quasi-static s |"
echo "|---:|---:|---:|---:|---:|"
for n in "${sizes[@]}"; do
  "$bin" generate prism --n "$n" --cluster --out "$dir/p.toml"
  check=$(median_us 5 "$bin" check "$dir/p.toml")
  statics=$(median_us 5 "$bin" statics "$dir/p.toml")
  deploy=$(median_us 3 "$bin" deploy "$dir/p.toml" --quasi-static --out "$dir/d.csv")
  coords=$("$bin" check "$dir/p.toml" | sed -n 's/^coordinates: //p')
  printf '| %d | %d | %s | %s | %s |\n' "$n" "$coords" "$(seconds "$check")" "$(seconds "$statics")" "$(seconds "$deploy")"
done
