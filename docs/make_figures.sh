#!/usr/bin/env bash
# Regenerate the figures the README shows (the paper's Section 5, reproduced).
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${BIN:-.venv/bin}
for ex in paper_continuous paper_continuous_switching paper_discrete paper_discrete_noise paper_discrete_switching ring10; do
  "$BIN/splitspec" simulate "examples/$ex.yaml" --out "out/figures/$ex" > /dev/null
  mkdir -p docs/figures
  cp "out/figures/$ex/errors.png" "docs/figures/${ex}_errors.png"
  cp "out/figures/$ex/states.png" "docs/figures/${ex}_states.png"
done
echo "figures written to docs/figures"
