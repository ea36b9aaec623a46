#!/usr/bin/env bash
# Writes the data and the goldens of tests/golden.rs with the `onsager` binary of this checkout:
#   cargo build --release && tests/golden/regenerate.sh
# Run it only when an estimator's numbers are meant to change, and say why in the commit.
set -euo pipefail
cd "$(dirname "$0")"
bin=../../target/release/onsager
"$bin" simulate --model double-well --t-end 4 --sample-every 0.5 --seed 3 --out dw.csv >/dev/null
"$bin" simulate --model duffing --t-end 5 --seed 4 --out duffing.csv >/dev/null
grep -v '^#' cases.txt | while read -r name data args; do
  # shellcheck disable=SC2086
  "$bin" estimate --data "$data" $args --out "$name.csv" --report "$name.json" >/dev/null || true
done
