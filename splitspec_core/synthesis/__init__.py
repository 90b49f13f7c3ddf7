"""Design and certificates: a scenario in, a :class:`~splitspec_core.synthesis.design_data.Design` and its verdicts out.

``designer.py`` the design (Sections 2-4: g or q over every graph the switching can use; the choice between the split
and the whole state), ``prelude.py`` what both share (decompositions, what nobody sees, cases, losses),
``approximate.py`` the policy for an approximate split, ``design_data.py`` the ``Design`` it returns (data; its analyses are functions of it, cached
per design); ``bounds.py`` the certificates' bounds for g and q, ``spectral.py`` spectral radii (exact or
matrix-free, never claiming more than was computed) and the one rule every certificate decides by (``certifies``), ``sampled_rates.py`` g for the sampled-data form;
``error_matrix.py`` the full mn x mn error map, ``conditioning.py`` margins and the transient constant;
``resilience.py`` single agent and arc losses, ``loss_certificate.py`` lossy networks, ``bad_data.py`` each
agent's test of its measurement and the certified fallback of a suspect sensor (``design.bad_data``),
``survivors.py`` the runtime's survivor verdict; ``noise_tuning.py`` the gains' tuning under noise;
``kalman.py`` the centralized Kalman predictor and its rate-shifted variant (the references under noise);
``whole_state.py`` the whole-state design (every agent averages its neighbours' whole estimates, gains from the
noise: ``design.consensus``, ``design.gains: optimal``), ``mixing.py`` what certifies it under switching (the mixing
and dwell-time bounds); ``fusion.py`` the fusion kind (matrix weights per exchange, each agent's gains the best
for the noise given the others': few exchanges) and ``fusion_kind.py`` it in a design (``design.consensus: fusion``:
the budget q, its certificate, what each agent is sent), ``exchange_limit.py`` the two-rate protocol's limit at q exchanges
(the Kalman predictor fed each sensor as late as the protocol delivers it), ``relay.py`` the relay kind (the
exchanges pass the sensors' samples on, each agent the Kalman predictor of what it holds: the protocol's limit,
``design.consensus: relay``); ``design_cache.py`` designs paid once
(kept in the process and on disk, keyed by content);
``verdict.py`` the certificate's verdict, computed once, ``report.py`` its rendering (``splitspec design``),
``advice.py`` the knobs a warning would name, each designed on the scenario and measured.
Imports ``scenarios`` and ``model``.
"""
