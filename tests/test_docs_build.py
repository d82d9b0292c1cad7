"""The site builds without a single warning: front page, the README's tour, the Markdown
guides (myst-parser) and the API reference from the docstrings, with a working search.

``docs/api.rst`` points autosummary at ``bikeid`` recursively, so every public module is
documented without a list to keep up to date. The build runs on a copy of ``docs/`` (and of
the README it includes) in a
temporary folder (autosummary writes its pages next to the sources, and parallel test
workers must not share or leave output in the checkout), with ``-W --keep-going``: every
docutils/numpydoc warning is reported, and any one fails the test.
"""

from __future__ import annotations

import pkgutil
import runpy
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

import bikeid

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def _public_modules() -> set[str]:
    """Every module of the installed package with no private component in its name."""
    return {
        m.name
        for m in pkgutil.walk_packages(bikeid.__path__, "bikeid.")
        if not any(part.startswith("_") for part in m.name.split("."))
    } | {"bikeid"}


def _copy_sources(root: Path) -> Path:
    """The Sphinx sources (conf.py, reST, Markdown guides, templates) without any earlier
    build output, in ``root/docs``, beside a copy of the README (``docs/tour.md`` includes
    ``../README.md``)."""
    dest = root / "docs"
    shutil.copytree(
        DOCS,
        dest,
        ignore=shutil.ignore_patterns("_build", "generated", "__pycache__"),
    )
    shutil.copy2(ROOT / "README.md", root / "README.md")
    return dest


@pytest.mark.slow  # ~60 s: imports every module and writes a page per module (~120)
def test_site_builds_without_warnings(tmp_path):
    """The site: front page, the README's tour, the Markdown guides and the API reference,
    built with ``-W`` (any warning fails), with a search index covering the guides."""
    pytest.importorskip("sphinx")
    pytest.importorskip("numpydoc")
    pytest.importorskip("myst_parser")
    before = _snapshot(DOCS)
    src = _copy_sources(tmp_path / "src")
    out = tmp_path / "html"
    t0 = time.perf_counter()
    res = subprocess.run(
        [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html"]
        + ["-d", str(tmp_path / "doctrees"), str(src), str(out)],
        capture_output=True,
        text=True,
        timeout=900,  # a hang guard; ~30 s on the idle 2-core CI machine, 10 min measured
        # on it while six other jobs ran (89 s of CPU): the guard must not fire under load
        cwd=tmp_path,
    )
    elapsed = time.perf_counter() - t0
    assert res.returncode == 0, f"sphinx-build failed after {elapsed:.0f} s:\n{res.stderr}"

    pages = {p.stem for p in (out / "generated").glob("*.html")}
    missing = _public_modules() - pages
    assert not missing, f"modules without an API page: {sorted(missing)}"
    assert "bikeid.sim._whipple_generated" not in pages
    assert _snapshot(DOCS) == before, "the build wrote into the checkout's docs/"
    _check_front_page_guides_and_search(out)


#: The pages the front page leads to first: the README's tour, the guides, the API.
FRONT = ("tour", "tutorial", "tutorial_own_logs", "identification", "uncertainty", "measured",
         "api")  # fmt: skip


def _check_front_page_guides_and_search(out: Path) -> None:
    """The front page links the tour, the guides and the API; each guide's page shows its
    own first heading (read here from the Markdown source); the tour page holds the
    README's tour; every guide is in the search index (a word of the tutorial found there,
    stemmed by Sphinx's own English stemmer)."""
    import json
    import re

    index = (out / "index.html").read_text(encoding="utf-8")
    for page in FRONT:
        assert f'href="{page}.html"' in index, page
    for md in sorted(DOCS.glob("*.md")):
        if md.stem == "tour":
            continue
        html = (out / f"{md.stem}.html").read_text(encoding="utf-8")
        title = md.read_text(encoding="utf-8").splitlines()[0].removeprefix("# ")
        words = re.sub(r"[`*]", "", title).split()[:3]  # the title as text, before markup
        assert all(w.replace("&", "&amp;") in html for w in words), (md.name, words)
    tour = re.sub(r"<[^>]+>", "", (out / "tour.html").read_text(encoding="utf-8"))
    assert "A tour" in tour and "bikeid critical-speeds --bicycle benchmark" in tour
    text = (out / "searchindex.js").read_text(encoding="utf-8")
    index_js = json.loads(text[text.index("(") + 1 : text.rindex(")")])
    docs = index_js["docnames"]
    assert set(FRONT) <= set(docs) and {p.stem for p in DOCS.glob("*.md")} <= set(docs)
    from sphinx.search.en import SearchEnglish

    term = SearchEnglish(options={}).stem("treadmill")  # in docs/tutorial.md, line 4
    assert "treadmill" in (DOCS / "tutorial.md").read_text(encoding="utf-8")
    hits = index_js["terms"][term]
    hits = hits if isinstance(hits, list) else [hits]
    assert docs.index("tutorial") in hits, (term, [docs[i] for i in hits])


def _snapshot(folder: Path) -> list[tuple[str, int]]:
    """Every file of the build outputs under ``folder`` with its modification time (ns).

    Only the output folders: the Markdown guides next to them may be edited meanwhile.
    """
    return sorted(
        (str(p.relative_to(folder)), p.stat().st_mtime_ns)
        for out in ("generated", "_build")
        for p in (folder / out).rglob("*")
    )


def test_plain_text_bars_are_escaped_only_in_prose():
    """conf.py's docstring hook: |x| in prose renders as text, reST structure is kept."""
    escape = runpy.run_path(str(DOCS / "conf.py"))["escape_plain_text_bars"]
    lines = [
        "Allowed |error|: 2 % of |lambda|, ``a | b`` and :math:`|x|` unchanged.",
        "",
        "Example::",
        "",
        "    |found - truth|",
        "",
        ".. math::",
        "",
        "   \\|x\\|_2",
        "",
        ">>> abs(-1) | 0",
        "",
        "| a line block",
        "",
        "+---+---+",
        "| a | b |",
        "+---+---+",
        "",
        "After |z|.",
    ]
    expected = list(lines)
    expected[0] = "Allowed \\|error\\|: 2 % of \\|lambda\\|, ``a | b`` and :math:`|x|` unchanged."
    expected[-1] = "After \\|z\\|."
    escape(None, "module", "m", None, {}, lines)
    assert lines == expected
