"""No raw Python warning reaches a command-line user: each becomes one ``note:`` line that
says what it means for the result (experiments.cli.WARNING_CONSEQUENCES); --debug shows
the raw warning."""

from __future__ import annotations

import warnings

import pytest

from bikeid.experiments import cli


def _warning_command(monkeypatch, category):
    """``bikeid eig`` replaced by a command that warns twice (the same message) and once
    more with another message, then succeeds."""
    from bikeid.experiments.cli import plant

    def cmd(args):
        for _ in range(2):
            warnings.warn("overflow encountered in exp", category, stacklevel=1)
        warnings.warn("invalid value encountered in divide", category, stacklevel=1)
        return 0

    monkeypatch.setattr(plant, "cmd_eig", cmd)


@pytest.mark.parametrize("category, meaning", [
    (RuntimeWarning, "the checks after it decide whether the result stands"),
    (UserWarning, "check the result that depends on it"),
    (FutureWarning, "this result is not affected"),
])  # fmt: skip
def test_each_warning_is_one_note_with_its_consequence(monkeypatch, capsys, category, meaning):
    _warning_command(monkeypatch, category)
    assert cli.main(["eig"]) == 0
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x]
    assert len(lines) == 2 and all(x.startswith("note: ") for x in lines), err
    assert all(meaning in x for x in lines), err
    assert "Warning:" not in err and "site-packages" not in err  # no raw warning, no path


def test_debug_shows_the_raw_warning(monkeypatch, capsys):
    """With --debug the warning is left to Python's own machinery (here pytest's recorder)."""
    _warning_command(monkeypatch, RuntimeWarning)
    with pytest.warns(RuntimeWarning, match="overflow encountered in exp"):
        assert cli.main(["eig", "--debug"]) == 0
    assert "note:" not in capsys.readouterr().err


def test_a_library_path_is_shortened_to_the_package():
    assert cli._short_path("/x/lib/python3.11/site-packages/numpy/linalg/_linalg.py") == (
        "numpy/linalg/_linalg.py"
    )
