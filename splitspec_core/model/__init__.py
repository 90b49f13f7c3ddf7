"""What every process needs at run time: the estimator's model and the pure per-agent math.

``steps.py`` the per-agent update steps (eqs. split-discrete-*, split_continuous_observer) shared by the
simulator and the agent processes, ``screening.py`` their bad-data tests for every agent at once (the simulator)
and the sensor events a run's rows imply; ``local_design.py`` one agent's ``V_i, K_i, P_i`` (computed alike by the
designer and by each agent from the scenario) with ``observability.py`` (the decomposition),
``gains.py`` (K_i, one registered function per local method; ``gain_registry.py`` the request every method takes,
the gain it returns and the registry; ``gain_target.py`` which modes a gain leaves alone),
``modal.py`` (balanced coordinates, eigenvalue clusters), ``subspaces.py`` and
``detectability.py`` (what no agent sees); ``graphs.py`` communication graphs and weights;
``plant.py`` the true system and initial values; ``network.py`` the switching signal and faults as
a plan, ``impairment.py`` losses, delays and partitions per message, ``streams.py`` the named seed
streams; ``rows.py`` the row schema of a run's records (every column once: the wire, the recorder, the files
and ``Trajectory`` derive theirs from it). Imports ``scenarios`` only: agents and the plant import this, never the design stack.
"""
