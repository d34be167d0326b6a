"""``python -m cartpole`` is the ``cartpole`` command."""

from cartpole.cli.main import main

raise SystemExit(main())
