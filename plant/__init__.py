"""The plant process (installed as ``splitspec_plant``): the true system, its noise, and every agent's
measurements.

- :mod:`.plant`: ``PlantNode``, which generates the true state and the measurements, one event time per tick
  (with :mod:`splitspec_core.model.plant`, shared with ``simulate``), inside the runtime's process shell;
- ``python -m splitspec_plant`` (:mod:`.__main__`), what ``splitspec plant`` runs.

It imports only ``splitspec_core`` and its ``runtime`` (docs/explanation/architecture.md).
"""
