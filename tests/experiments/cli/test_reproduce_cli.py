"""``bikeid reproduce`` says each stage once and counts only the files it wrote for the user.

The studies themselves are tested end to end in tests/experiments/papers/test_reproduce.py
(slow); here the library's ``reproduce`` is replaced by a stand-in that announces stages
through the library's own :func:`~bikeid.experiments.papers.reproduce.stage_announcer` and
writes known files, so the counts are known exactly.
"""

from __future__ import annotations

import io

import pytest

from bikeid.dataset.files import atomic_write_text
from bikeid.experiments.cli import main
from bikeid.experiments.papers import reproduce as rep
from bikeid.experiments.progress import LineProgress

STAGES = ("Chen & Dao Fig. 2 / eqs. 5-6 (identification at 4.2 m/s)", "sweep summary")


@pytest.fixture
def stand_in(monkeypatch):
    """A ``reproduce`` that announces STAGES and writes the names it is given."""
    names: list[str] = ["report.md", "summary.json", "figs/a.png"]

    def fake(out, quick=False, workers=None, log=print, bicycle="benchmark", progress=None,
             dask=None):  # fmt: skip
        stage = rep.stage_announcer(log, progress, len(STAGES))
        for name in STAGES:
            stage(name)
        for n in names:
            atomic_write_text(f"{out}/{n}", n)
        return {}

    monkeypatch.setattr(rep, "reproduce", fake)
    return names


def test_each_stage_announced_once_and_only_user_files_counted(stand_in, tmp_path, capsys):
    out = tmp_path / "rep"
    assert main(["reproduce", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    for name in STAGES:  # off a terminal: the stage lines of the progress, not a 2nd log line
        assert err.count(name) == 1, err
    assert (out / ".bikeid-folder.json").is_file()  # the marker exists but is not counted
    last = err.splitlines()[-1]
    assert last.startswith("bikeid reproduce: wrote 3 files: "), last
    assert ".bikeid" not in last
    # again into the same folder, rewriting one file: one written (the others are older)
    stand_in[:] = ["summary.json"]
    assert main(["reproduce", "--out", str(out)]) == 0
    last = capsys.readouterr().err.splitlines()[-1]
    assert last == f"bikeid reproduce: wrote 1 file: {out / 'summary.json'}"


def test_stage_announcer_says_a_stage_once_either_way():
    """With a progress (bar or stage lines) the stage goes there only; without, to the log."""
    logged: list[str] = []
    stream = io.StringIO()
    stage = rep.stage_announcer(logged.append, LineProgress("reproduce", stream), 2)
    stage("first stage (detail)")
    stage("second")
    assert logged == []
    assert stream.getvalue().splitlines() == ["reproduce: [0/2] first stage (detail)",
                                              "reproduce: [1/2] second"]  # fmt: skip
    stage = rep.stage_announcer(logged.append, None, 2)
    stage("first stage (detail)")
    assert logged == ["[reproduce] first stage (detail) ..."]
