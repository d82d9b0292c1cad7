"""``python -m bikeid.experiments.cli``: the ``bikeid`` command."""

from bikeid.experiments.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
