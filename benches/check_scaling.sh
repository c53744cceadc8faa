#!/usr/bin/env bash
# Wall time of `tensegrity check` (parse, validate, form finding) on generated clustered n-prisms:
# median of 5 runs per size, in seconds (ms resolution). Usage: bash benches/check_scaling.sh [N ...]
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -q
bin=target/release/tensegrity
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
sizes=("$@")
[ ${#sizes[@]} -gt 0 ] || sizes=(120 240 400 999)
echo "| struts | coordinates | check median s |"
echo "|---:|---:|---:|"
for n in "${sizes[@]}"; do
  "$bin" generate prism --n "$n" --cluster --out "$dir/p.toml"
  times=()
  for _ in 1 2 3 4 5; do
    s=$(date +%s%N)
    "$bin" check "$dir/p.toml" >/dev/null
    e=$(date +%s%N)
    times+=("$(( (e - s) / 1000 ))")
  done
  median=$(printf '%s\n' "${times[@]}" | sort -g | sed -n 3p)
  coords=$("$bin" check "$dir/p.toml" | sed -n 's/^coordinates: //p')
  printf '| %d | %d | %d.%03d |\n' "$n" "$coords" "$((median / 1000000))" "$(((median / 1000) % 1000))"
done
