"""``python -m bikeid``: the ``bikeid`` command."""

from bikeid.experiments.cli import main

raise SystemExit(main())
