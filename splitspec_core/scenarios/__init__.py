"""The problem statement: what a scenario file (or ``ss.scenario``) says, checked, and nothing computed from it.

``specs.py`` the frozen :class:`Scenario` and its sections' dataclasses; ``keys.py`` every key of the file
declared once (kind, default, words, doc line) and ``gain_methods.py`` the words of ``design.gains`` and what each
needs; ``checks.py`` value checks (one-line
errors naming the key); ``sections.py`` the parsers of each section, ``design_section.py`` the ``design:``
section (gains, consensus, g or q), ``network_section.py`` the ``network:``
section (losses, delays, partitions), ``faults.py`` the kinds of fault (one registered class each: parsing,
effect in the simulator and the runtime, event, mark), ``sources.py`` live sources; ``load.py`` the one validation path
(``load_scenario``, ``parse_scenario_text``) and ``yaml12.py`` its numbers as YAML 1.2 reads them; ``files.py`` models in ``.npz``/``.mat`` files (``system.file``),
``control.py`` python-control plants; ``noise.py`` the process and measurement noise (per state, per
agent, per output) and the covariances they mean; ``inputs.py`` known inputs (``system.B``, ``system.u``) and
``sampling.py`` the zero-order hold of ``system.sample``; ``labels.py`` state and output names;
``measurements.py`` recorded measurements files, ``replay.py`` a recorded run's faults as a scenario,
``generate.py`` random scenarios, ``summary.py`` what ``print(scenario)`` shows. Imports nothing of splitspec_core but ``errors``: every other layer
stands on it.
"""
