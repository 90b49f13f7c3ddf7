"""Studies over designs and trajectories: baselines, comparisons, sweeps, runs without a truth.

``baselines.py`` the centralized Kalman predictor and the KCF, ``comparison.py`` ``ss.compare`` (the
estimator against them under noise), ``transients.py`` how long each of compare's rows must run (its certified
transient) and the steps compare chooses, ``sweeps.py`` ``ss.network_sweep``, ``rate_sweep.py`` the steady RMS
against the rate asked (``compare --sweep-rate``), ``no_truth.py`` what a run on
measurements shows without the true state (residuals, disagreement, a reference Kalman filter),
``few_exchanges.py`` the fusion kind run on measurements and Rego's steady-state distributed Kalman filter (the
baseline at one exchange per step).
Imports every layer below it; nothing below imports it.
"""
