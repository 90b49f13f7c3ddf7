"""``python -m splitspec_orchestrator ARGS``: the ``splitspec`` command."""

import sys

from splitspec_orchestrator.cli import main

sys.exit(main())
