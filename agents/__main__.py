"""``python -m splitspec_agents ...``: the agent process (what ``splitspec agent`` runs)."""

from splitspec_agents.agent import cli_main

raise SystemExit(cli_main())
