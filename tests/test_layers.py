"""The package's shape: one installed top-level name, one-way data flow, no import cycles.

The design fixes the stages and their order (docs: README "Layout and data flow"):

    bikeid.sim -> bikeid.controllers -> bikeid.dataset -> bikeid.ident -> bikeid.experiments

A module may import its own stage and earlier ones, never a later one, and the module
import graph has no cycles.  Every import of a stage is spelled ``bikeid.<stage>`` (or is
relative inside one stage): a bare ``import sim`` would only work from the repository root
and would pick up any unrelated top-level ``sim`` package in a user's environment.  The
imports are read from the source with :mod:`ast`, including imports inside functions
(a lazy import still makes the dependency).
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("sim", "controllers", "dataset", "ident", "experiments")
RANK = {s: i for i, s in enumerate(STAGES)}


#: Root modules besides the package's ``__init__`` (after every stage: ``bikeid.testing``
#: builds on the experiments; no stage may import them).
ROOT_MODULES = ("__main__", "testing")


def _modules() -> dict[str, Path]:
    out = {"bikeid": ROOT / "__init__.py"}
    out.update({f"bikeid.{m}": ROOT / f"{m}.py" for m in ROOT_MODULES})
    for stage in STAGES:
        for f in sorted((ROOT / stage).rglob("*.py")):  # subpackages too
            parts = ["bikeid", *f.relative_to(ROOT).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = f
    return out


def _imports(name: str, path: Path) -> list[tuple[str, int]]:
    """(imported module, line) for every import statement in the file."""
    is_pkg = path.name == "__init__.py"
    package = name if is_pkg else name.rsplit(".", 1)[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
                # "from . import x" may name a submodule
                found += [(f"{mod}.{a.name}", node.lineno) for a in node.names]
                found.append((mod, node.lineno))
            else:
                found.append((node.module, node.lineno))
                found += [(f"{node.module}.{a.name}", node.lineno) for a in node.names]
    return found


def _graph() -> tuple[dict[str, set[str]], list[str]]:
    mods = _modules()
    graph: dict[str, set[str]] = {m: set() for m in mods}
    bare = []
    for name, path in mods.items():
        for target, line in _imports(name, path):
            top = target.split(".")[0]
            if top in STAGES:
                bare.append(f"{path.relative_to(ROOT)}:{line} imports {target!r}")
            if target in mods and target != name:
                graph[name].add(target)
    return graph, bare


def test_every_stage_import_is_spelled_bikeid():
    _, bare = _graph()
    assert not bare, "imports without the bikeid. prefix:\n" + "\n".join(bare)


def test_imports_follow_the_data_flow():
    graph, _ = _graph()
    wrong = []
    top = len(STAGES)  # the root modules come after every stage
    for src, targets in graph.items():
        if src == "bikeid":
            continue
        s = RANK.get(src.split(".")[1], top)
        for t in sorted(targets):
            if t == "bikeid":
                continue
            if RANK.get(t.split(".")[1], top) > s:
                wrong.append(f"{src} imports {t} (a later stage)")
    print(f"{len(graph)} modules, {sum(map(len, graph.values()))} internal imports checked")
    assert not wrong, "\n".join(wrong)


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_no_import_cycles_between_modules():
    graph, _ = _graph()
    # A package __init__ re-exporting its own submodules is not a cycle of two topics.
    pruned = {m: {t for t in ts if not t.startswith(m + ".")} for m, ts in graph.items()}
    assert not _cycles(pruned), f"import cycles: {_cycles(pruned)}"


def test_checker_sees_violations():
    """The checker itself can fail: a later-stage import and a cycle are both reported."""
    g = {"bikeid.sim.a": {"bikeid.ident.b"}, "bikeid.ident.b": {"bikeid.sim.a"}}
    assert _cycles(g) == [["bikeid.ident.b", "bikeid.sim.a"]]
    tree = _imports("bikeid.sim.x", ROOT / "sim" / "linear.py")
    assert any(t.startswith("bikeid.sim.") for t, _ in tree)  # relative imports resolved


def _installed(code: str) -> subprocess.CompletedProcess:
    """Run ``code`` in the test's interpreter, isolated from the repository checkout:
    ``-I`` drops the current folder and PYTHONPATH from sys.path, and it runs elsewhere."""
    return subprocess.run(
        [sys.executable, "-I", "-c", code],
        capture_output=True,
        text=True,
        cwd=os.path.expanduser("~") if Path.home().exists() else "/",
        check=False,
    )


def test_installed_distribution_has_one_top_level_name():
    """Outside the repository, ``import bikeid.sim`` works and ``import sim`` does not, and
    the installed distribution puts nothing but ``bikeid`` at the top of site-packages
    (a regular install: the files it recorded; an editable one: its finder's mapping)."""
    probe = _installed(
        "import importlib.metadata as m, importlib.util as u, json, sys\n"
        "d = m.distribution('bikeid')\n"
        "files = [str(f) for f in d.files or []]\n"
        "tops = set()\n"
        "for f in files:\n"
        "    top = f.split('/')[0]\n"
        "    if top.endswith(('.dist-info', '.egg-info')) or top in ('..', '__pycache__'):\n"
        "        continue\n"
        "    if top.startswith('__editable__') and top.endswith('finder.py'):\n"
        "        mod = __import__(top[:-3])\n"
        "        tops |= set(mod.MAPPING) | set(mod.NAMESPACES)\n"
        "    elif top.endswith('.pth'):\n"
        "        continue\n"
        "    else:\n"
        "        tops.add(top.removesuffix('.py'))\n"
        "print(json.dumps({'tops': sorted(tops),\n"
        "  'stages': [u.find_spec('bikeid.' + n) is not None\n"
        "             for n in ('sim', 'controllers', 'dataset', 'ident', 'experiments')]}))\n"
    )
    if probe.returncode != 0 and "PackageNotFoundError" in probe.stderr:
        pytest.skip("bikeid is not installed in this interpreter (pip install . first)")
    assert probe.returncode == 0, probe.stderr
    res = json.loads(probe.stdout)
    assert res["tops"] == ["bikeid"], res
    assert all(res["stages"]), res
    bare = _installed("import sim")
    assert bare.returncode != 0 and "No module named 'sim'" in bare.stderr, bare.stderr


def test_every_subpackage_is_installed():
    """Each folder of the stages holding an ``__init__.py`` is listed in pyproject.toml's
    packages (a missing one would be left out of the wheel)."""
    import tomllib

    listed = set(
        tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    )
    found = {m for m, f in _modules().items() if f.name == "__init__.py"}
    assert found <= listed, f"not in pyproject.toml packages: {sorted(found - listed)}"
