"""``python -m splitspec_plant ...``: the plant process (what ``splitspec plant`` runs)."""

from splitspec_plant.plant import cli_main

raise SystemExit(cli_main())
