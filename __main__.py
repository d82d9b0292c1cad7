"""``python -m bikeid``: the ``bikeid`` command."""

# Ctrl-C while the command's modules are imported: one line and exit status 130, by the
# handler the package installs first (bikeid/__init__.py); main() restores Python's.
from bikeid.experiments.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
