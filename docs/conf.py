"""Sphinx configuration of bikeid's API reference (numpydoc docstrings, autosummary).

Build it from the repository root with ``python -m sphinx -b html docs docs/_build``
(``bikeid`` must be importable: ``pip install -e .``). Autosummary walks the package
recursively from ``api.rst``, so no module is listed here: a module added, moved or renamed
is documented on the next build. ``tests/test_docs_build.py`` builds a copy of this folder
with ``-W`` (every warning is an error), so a docstring that does not render fails the tests.

The site's front page (``index.rst``) leads to the README's tour (``tour.md`` includes
``../README.md``), the Markdown guides (read by ``myst-parser`` as they are written for
GitHub: the tutorials, identification, uncertainty and measured data first, the others
under "More guides") and the API reference, with one search over all of them.
"""

from __future__ import annotations

import importlib.metadata
import pkgutil
import re

import bikeid

# -- Project -------------------------------------------------------------------------------
project = "bikeid"
author = "the bikeid developers"
copyright = "2026, the bikeid developers"
release = importlib.metadata.version("bikeid")
version = ".".join(release.split(".")[:2])

# -- General -------------------------------------------------------------------------------
extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "myst_parser",  # the Markdown guides and the README's tour
]
root_doc = "index"
templates_path = ["_templates"]  # autosummary: a page per module, every docstring on it
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
# Builds are outputs, not sources; every Markdown guide is a page (index.rst lists them).
exclude_patterns = ["_build"]
# The README (the tour page) links CHANGELOG.md, a repository file that is no page here;
# every other link between the README and the guides must resolve (-W).
nitpick_ignore = [("myst", "CHANGELOG.md")]
default_role = "code"  # `x` in a docstring renders as code, as numpydoc writers intend

# -- autosummary / autodoc -----------------------------------------------------------------
autosummary_generate = True  # writes docs/generated/ (gitignored)
autosummary_generate_overwrite = True
autosummary_imported_members = False  # a name is documented in the module defining it only
autosummary_ignore_module_all = True  # ... even when a package re-exports it in __all__
# Private modules (``bikeid.sim._whipple_generated``, the sympy-emitted equations) and
# private names are skipped by autosummary's recursive module template.
# Autosummary imports every submodule it finds, private ones included, before it skips
# them. A ``__main__`` module (``python -m bikeid``, ``python -m bikeid.experiments.cli``)
# runs the command line on import, with sphinx-build's own arguments; mocking each one (found
# by walking the package, which imports packages only) keeps it from running.
autosummary_mock_imports = [
    m.name
    for m in pkgutil.walk_packages(bikeid.__path__, "bikeid.", onerror=lambda name: None)
    if m.name.rsplit(".", 1)[-1] == "__main__"
]
autodoc_typehints = "none"  # numpydoc's Parameters/Returns sections carry the types
autodoc_member_order = "bysource"

# -- numpydoc ------------------------------------------------------------------------------
numpydoc_show_class_members = False  # autoclass :members: renders them in full
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False  # types are prose ("array_like, shape (n,)"), not targets
numpydoc_validation_checks: set[str] = set()  # tests/test_docstrings.py is the style gate


def _load_numpydoc_template_once() -> None:
    """numpydoc (1.x) builds a new Jinja environment for every docstring it renders and
    compiles its one template (``numpydoc_docstring.rst``) again each time: ~3,900 compiles
    in this site, a quarter of the build's CPU (62 -> 48 s, one build each on the 2-core
    VM). Within one build the template a name resolves to is the same, so each is compiled
    once and reused; the pages are unchanged (the same template renders them)."""
    import numpydoc.docscrape_sphinx as ds

    compiled: dict[str, object] = {}

    class OneCompile(ds.SandboxedEnvironment):
        def get_template(self, name, *args, **kwargs):
            if name not in compiled:
                compiled[name] = super().get_template(name, *args, **kwargs)
            return compiled[name]

    ds.SandboxedEnvironment = OneCompile


_load_numpydoc_template_once()

# -- HTML ----------------------------------------------------------------------------------
html_theme = "alabaster"
html_title = f"bikeid {release}: tour, guides and API reference"
html_static_path: list[str] = []
# No global navigation tree in the sidebar: with one page per function and class it lists
# ~700 entries on every page (a fifth of the write time, and unreadable); pages link up via
# previous/next (relations) and the module pages' tables.
html_sidebars = {"**": ["about.html", "relations.html", "searchbox.html"]}
html_copy_source = False  # the sources are generated stubs; nothing to show
html_show_sourcelink = False


# -- Plain-text absolute values ------------------------------------------------------------
# The docstrings write formulas as plain text, and |x| is an absolute value or a norm there
# (``|lambda|``, ``|found - truth|``, ``|E(t) - E(0)|``); in reST the same characters are a
# substitution reference, and no docstring defines a substitution, so docutils reports
# "Undefined substitution referenced" for every one (dozens of modules). The notation is
# the intended one and reads correctly in ``help()``, so instead of rewriting it everywhere
# each bar in prose is escaped before numpydoc and docutils see it: it renders as a plain
# "|". Bars are left alone where reST gives them meaning or shows text verbatim: inline
# literals and interpreted text (``...``, `...`, :role:`...`), literal blocks (after "::"),
# directive bodies (e.g. ``.. math::``, where \| would be LaTeX's norm), doctest blocks, grid
# tables and line blocks. Any other docutils warning still fails ``-W``.
_LITERAL_SPAN = re.compile(r"``.+?``|(?::[\w:+.-]+:)?`[^`]+`_{0,2}", re.DOTALL)
_ESCAPE_BAR = re.compile(r"(?<!\\)\|")


def _escape_bars(text: str) -> str:
    """Escape every ``|`` of ``text`` outside inline literals and interpreted text."""
    out, last = [], 0
    for m in _LITERAL_SPAN.finditer(text):
        out.append(_ESCAPE_BAR.sub(r"\\|", text[last : m.start()]))
        out.append(m.group())
        last = m.end()
    out.append(_ESCAPE_BAR.sub(r"\\|", text[last:]))
    return "".join(out)


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip())


def _verbatim_line(stripped: str) -> bool:
    """A line where a bar is reST structure: grid-table border/row, line block, doctest."""
    return (
        stripped.startswith(("+-", "+=", "| ", ">>>", "..."))
        or (stripped.startswith("|") and stripped.endswith("|") and stripped.count("|") > 2)
        or stripped == "|"
    )


def escape_plain_text_bars(app, what, name, obj, options, lines: list[str]) -> None:
    """``autodoc-process-docstring`` handler: escape plain-text absolute-value bars.

    Parameters
    ----------
    app, what, name, obj, options
        As Sphinx passes them (unused).
    lines : list of str
        The docstring's lines, edited in place (a backslash added before each prose bar;
        the number of lines is unchanged).
    """
    verbatim_indent = None  # inside a literal block / directive body indented past this
    in_doctest = False
    paragraph: list[int] = []  # indices of the prose lines of the current paragraph

    def flush() -> None:
        if paragraph:
            escaped = _escape_bars("\n".join(lines[i] for i in paragraph)).split("\n")
            for i, new in zip(paragraph, escaped, strict=True):
                lines[i] = new
            paragraph.clear()

    for i, line in enumerate(lines):
        stripped = line.strip()
        if not stripped:
            flush()
            in_doctest = False
            continue
        if verbatim_indent is not None:
            if _indent(line) > verbatim_indent:
                continue
            verbatim_indent = None
        if in_doctest or stripped.startswith(">>>"):
            flush()
            in_doctest = True
            continue
        if stripped.startswith(".. "):  # a directive (its body is verbatim here) or comment
            flush()
            verbatim_indent = _indent(line)
            continue
        if _verbatim_line(stripped):
            flush()
        else:
            paragraph.append(i)
        if stripped.endswith("::"):  # a literal block follows, indented past this line
            flush()
            verbatim_indent = _indent(line)
    flush()


def setup(app) -> None:
    """Register :func:`escape_plain_text_bars` to run before numpydoc (priority 500)."""
    app.connect("autodoc-process-docstring", escape_plain_text_bars, priority=400)
