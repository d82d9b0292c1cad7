"""The public API's docstrings follow numpydoc in python-control's style.

For every public module of every stage and its subpackages (:data:`DOCUMENTED_MODULES`:
all of them but the command-line modules ``experiments.cli.*``, which only parse arguments
and print):

- every function named in the module's ``__all__`` (or, without ``__all__``, every public
  function defined in it) has a docstring with a ``Parameters`` section (numpydoc
  underline) if it takes parameters other than ``self``/``cls``, and a ``Returns`` or
  ``Yields`` section unless its return annotation is ``None``;
- every class named there has a docstring with an ``Attributes`` or ``Parameters``
  section, and each of its public methods (defined in the class, not inherited; dunders
  skipped) obeys the function rule; a public property has a non-empty docstring.

Each package (:data:`DOCUMENTED_PACKAGES`, subpackages included) must have a docstring that
names every public module and subpackage of its folder (``bikeid.<package>.<module>`` or
``:mod:`.module```) and names no module that does not exist, so the one-line-per-module list stays
true as modules are added.
"""

from __future__ import annotations

import importlib
import inspect
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("sim", "controllers", "dataset", "ident", "experiments")

def _package_dirs() -> dict[str, Path]:
    """Every package of the stages, subpackages included: dotted name -> folder."""
    out = {}
    for stage in STAGES:
        for init in sorted((ROOT / stage).rglob("__init__.py")):
            out[".".join(("bikeid", *init.parent.relative_to(ROOT).parts))] = init.parent
    return out


DOCUMENTED_PACKAGES = tuple(_package_dirs())


def _section(doc: str, title: str) -> bool:
    """True if ``doc`` (cleaned) has a numpydoc section ``title`` with its underline."""
    return re.search(rf"^{title}\n-{{{len(title)}}}\s*$", doc, re.MULTILINE) is not None


def _returns_none(sig: inspect.Signature) -> bool:
    ann = sig.return_annotation
    return ann is None or ann == "None" or ann is type(None)


def check_function(func, qualname: str, method: bool = False) -> list[str]:
    """Problems with one function's docstring (empty list if it complies)."""
    func = inspect.unwrap(getattr(func, "py_func", func))  # numba dispatchers, decorators
    doc = inspect.getdoc(func) or ""
    if not doc.strip():
        return [f"{qualname}: no docstring"]
    problems = []
    sig = inspect.signature(func)
    params = list(sig.parameters)
    if method and params and params[0] in ("self", "cls"):
        params = params[1:]
    if params and not _section(doc, "Parameters"):
        problems.append(f"{qualname}: takes {params} but has no 'Parameters' section")
    if not _returns_none(sig) and not (_section(doc, "Returns") or _section(doc, "Yields")):
        problems.append(f"{qualname}: no 'Returns' or 'Yields' section (annotate -> None?)")
    return problems


def check_class(cls, qualname: str) -> tuple[list[str], int]:
    """Problems with a class and its public methods; also the number of methods checked."""
    problems = []
    doc = inspect.getdoc(cls) or ""
    if not (_section(doc, "Attributes") or _section(doc, "Parameters")):
        problems.append(f"{qualname}: class docstring has no 'Attributes' or 'Parameters'")
    n = 0
    for name, member in vars(cls).items():
        if name.startswith("_"):
            continue
        where = f"{qualname}.{name}"
        if isinstance(member, property):
            n += 1
            if not (inspect.getdoc(member) or "").strip():
                problems.append(f"{where}: property has no docstring")
        elif isinstance(member, (staticmethod, classmethod)):
            n += 1
            problems += check_function(
                member.__func__, where, method=isinstance(member, classmethod)
            )
        elif inspect.isfunction(member):
            n += 1
            problems += check_function(member, where, method=True)
    return problems, n


def check_module(modname: str) -> tuple[list[str], dict[str, int]]:
    """Problems in one module, and counts of the functions, classes and methods checked."""
    mod = importlib.import_module(modname)
    public = getattr(mod, "__all__", None)
    if public is None:
        public = [
            n
            for n, obj in vars(mod).items()
            if not n.startswith("_")
            and (inspect.isfunction(obj) or inspect.isclass(obj))
            and getattr(obj, "__module__", None) == modname
        ]
    problems: list[str] = []
    counts = {"functions": 0, "classes": 0, "methods": 0}
    for name in public:
        obj = getattr(mod, name)
        where = f"{modname}.{name}"
        if inspect.isclass(obj):
            counts["classes"] += 1
            found, n = check_class(obj, where)
            problems += found
            counts["methods"] += n
        elif inspect.isfunction(inspect.unwrap(getattr(obj, "py_func", obj))):
            counts["functions"] += 1
            problems += check_function(obj, where)
    return problems, counts


def _discovered() -> set[str]:
    """Modules ``bikeid.<stage>.<name>`` the convention applies to (from the files)."""
    out = set()
    for package, folder in _package_dirs().items():
        if package.startswith("bikeid.experiments.cli"):
            continue
        for f in folder.glob("*.py"):
            if not f.stem.startswith("_"):
                out.add(f"{package}.{f.stem}")
    return out


#: Every public module of every stage except the command-line modules (all comply now; a
#: new module is covered the moment its file exists).
DOCUMENTED_MODULES = tuple(sorted(_discovered()))


def test_every_stage_is_covered():
    stages = {m.split(".")[1] for m in DOCUMENTED_MODULES}
    assert stages == set(STAGES), stages
    assert len(DOCUMENTED_MODULES) >= 50, len(DOCUMENTED_MODULES)


# -- the convention ----------------------------------------------------------------------
@pytest.mark.parametrize("modname", DOCUMENTED_MODULES)
def test_module_complies(modname):
    problems, _ = check_module(modname)
    assert not problems, "\n".join(problems)


def test_count_checked(capsys):
    total = {"functions": 0, "classes": 0, "methods": 0}
    for modname in DOCUMENTED_MODULES:
        _, counts = check_module(modname)
        for k, v in counts.items():
            total[k] += v
    with capsys.disabled():
        print(
            f"\ndocstrings checked: {total['functions']} functions, {total['classes']} classes, "
            f"{total['methods']} methods in {len(DOCUMENTED_MODULES)} modules"
        )
    assert total["functions"] > 0 and total["methods"] > 0


# -- the checker can fail ----------------------------------------------------------------
def _summary_only(x: float, y: float = 1.0) -> float:
    """Just a summary line, no sections."""
    return x * y


def _no_return_section(x: float) -> float:
    """Has parameters but no returns.

    Parameters
    ----------
    x : float
        A value.
    """
    return x


def _returns_nothing(x: float) -> None:
    """Returns None, so no Returns section is needed.

    Parameters
    ----------
    x : float
        A value.
    """


def _generator(n: int):
    """Yield 0..n-1.

    Parameters
    ----------
    n : int
        How many.

    Yields
    ------
    int
    """
    yield from range(n)


def _undocumented(x):
    return x


class _NoAttributes:
    """A class without an Attributes or Parameters section."""

    def method(self, a: int) -> int:
        """No sections."""
        return a


def test_checker_self_check():
    summary = check_function(_summary_only, "_summary_only")
    assert any("'Parameters'" in p for p in summary)
    assert any("'Returns'" in p for p in summary)
    assert check_function(_no_return_section, "f") == ["f: no 'Returns' or 'Yields' section "
                                                       "(annotate -> None?)"]
    assert check_function(_undocumented, "g") == ["g: no docstring"]
    assert check_function(_returns_nothing, "h") == []
    assert check_function(_generator, "k") == []
    problems, n = check_class(_NoAttributes, "C")
    assert n == 1 and len(problems) == 3, problems


# -- stage package docstrings ------------------------------------------------------------
@pytest.mark.parametrize("package", DOCUMENTED_PACKAGES)
def test_package_docstring_lists_its_modules(package):
    folder = _package_dirs()[package]
    doc = (importlib.import_module(package).__doc__ or "").strip()
    assert doc, f"{package} has no docstring"
    present = {f.stem for f in folder.glob("*.py") if not f.stem.startswith("_")}
    present |= {d.name for d in folder.iterdir() if (d / "__init__.py").exists()}
    # a child is named in full (bikeid.pkg.child) or relative to the package (:mod:`.child`)
    named = set(re.findall(rf"{re.escape(package)}\.([A-Za-z_]\w*)", doc))
    named |= set(re.findall(r":mod:`~?\.([A-Za-z_]\w*)`", doc))
    unlisted = sorted(present - named)
    stale = sorted(named - present)
    assert not unlisted, f"{package} docstring does not list modules {unlisted}"
    assert not stale, f"{package} docstring lists modules that do not exist: {stale}"
