"""``python -m cartpole`` is the ``cartpole`` command."""

from cartpole.cli.main import run_main

raise SystemExit(run_main())
