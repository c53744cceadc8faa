#!/usr/bin/env bash
# Step cost of ground contact. 1) A scene without contact (prism3) as before: run this script on
# two checkouts, or compare with the table in docs/benchmarks.md. 2) The six-bar robot rolling
# (config/scenes/sixbar.toml: 4000 steps of 1 ms from the scene's pose through its roll) with its
# stick-slip friction, and with the regularized law at three regularization speeds. Per row: `tensegrity bench steps` (median, mean, largest wall
# time per step; Newton iterations and factorizations per step), median of 3 runs.
# Usage: bash benches/contact_steps.sh
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -q --bin tensegrity
bin=target/release/tensegrity
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
row() { # label scene steps
  local out=() line
  for _ in 1 2 3; do
    line=$("$bin" bench steps "$2" --steps "$3" | tail -1)
    out+=("$(sed -E 's/.*median ([0-9.]+) us\/step, mean ([0-9.]+), max ([0-9.]+); Newton ([0-9.]+)\/step, factorizations ([0-9.]+)\/step.*/\1 \2 \3 \4 \5/' <<<"$line")")
  done
  printf '%s\n' "${out[@]}" | sort -g | sed -n 2p | awk -v l="$1" '{printf "| %s | %s | %s | %s | %s | %s |\n", l, $1, $2, $3, $4, $5}'
}
echo "| scene | median us/step | mean | largest | Newton/step | factorizations/step |"
echo "| --- | ---: | ---: | ---: | ---: | ---: |"
row "prism3 (no contact)" config/scenes/prism3.toml 5000
row "sixbar, stick-slip friction, k_t 2e4 N/m (bundled)" config/scenes/sixbar.toml 4000
for vs in 1e-3 1e-4 1e-5; do
  sed -e '/^stick_stiffness/d' -e "s/^mu = 0.8$/mu = 0.8\nstiction_speed = $vs/" config/scenes/sixbar.toml >"$dir/sixbar.toml"
  row "sixbar, regularized friction, stiction_speed $vs m/s" "$dir/sixbar.toml" 4000
done
