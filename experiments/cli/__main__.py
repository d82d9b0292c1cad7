"""``python -m bikeid.experiments.cli``: the ``bikeid`` command."""

from bikeid.experiments.cli import main

raise SystemExit(main())
