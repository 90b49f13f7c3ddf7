#!/usr/bin/env bash
# Regenerate the figures the docs show (docs/explanation/method.md: the paper's Section 5, reproduced).
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${BIN:-.venv/bin}
for ex in paper_continuous paper_continuous_switching paper_discrete paper_discrete_noise paper_discrete_switching ring10 ring10_faults; do
  "$BIN/splitspec" simulate "examples/$ex.yaml" --out "out/figures/$ex" > /dev/null
  mkdir -p docs/figures
  cp "out/figures/$ex/errors.png" "docs/figures/${ex}_errors.png"
  cp "out/figures/$ex/states.png" "docs/figures/${ex}_states.png"
done
echo "figures written to docs/figures"
# estimation quality under noise (docs/how-to/compare.md)
"$BIN/splitspec" compare examples/paper_discrete_noise.yaml --out out/figures/compare_paper --seeds 20 --steps 80 --sweep > /dev/null
"$BIN/splitspec" compare examples/ring10_noise.yaml --out out/figures/compare_ring10 --seeds 10 > /dev/null
cp out/figures/compare_paper/compare_ratios.png docs/figures/compare_paper_ratios.png
cp out/figures/compare_paper/compare_errors.png docs/figures/compare_paper_errors.png
cp out/figures/compare_paper/sweep.png docs/figures/compare_paper_sweep_q.png
cp out/figures/compare_ring10/compare_ratios.png docs/figures/compare_ring10_ratios.png
echo "compare figures written to docs/figures"
# networks that misbehave (docs/how-to/networks.md)
"$BIN/splitspec" compare examples/ring10_noise.yaml --out out/figures/loss_sweep --seeds 20 --steps 200 \
  --sweep-loss 0 0.05 0.1 0.2 0.4 > /dev/null
"$BIN/splitspec" compare examples/ring10_lossy.yaml --out out/figures/deadline_sweep --seeds 20 --steps 200 \
  --sweep-deadline 0.0015 0.002 0.0025 0.003 > /dev/null
cp out/figures/loss_sweep/loss_sweep.png docs/figures/loss_sweep.png
cp out/figures/deadline_sweep/deadline_sweep.png docs/figures/deadline_sweep.png
echo "sweep figures written to docs/figures"
# what each rate costs in noise (docs/how-to/compare.md)
"$BIN/splitspec" compare examples/ieee14_pmu.yaml --out out/figures/rate_sweep --seeds 2 --steps 3000 \
  --sweep-rate 0.1 0.2 0.3 0.4 0.5 0.7 1.0 > /dev/null
cp out/figures/rate_sweep/rate_sweep.png docs/figures/rate_sweep_ieee14.png
echo "rate sweep figure written to docs/figures"
