"""Strict readers of the JSON and YAML text a user hands to bikeid, and the one converter
of bikeid's values to plain JSON types (:func:`to_jsonable`, :func:`dump_json`).

Python's ``json`` and PyYAML accept things that silently change a user's numbers:
duplicate keys (the last one wins), ``NaN``/``Infinity`` in JSON, and nesting deep
enough to exhaust the interpreter's stack.  :func:`loads_json` and :func:`loads_yaml`
refuse each with an :class:`~bikeid.sim.errors.InputError` naming the file and the
problem.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

from .errors import InputError

__all__ = ["MAX_DEPTH", "dump_json", "loads_json", "loads_yaml", "to_jsonable"]

#: Deepest nesting of lists/mappings accepted (bikeid's files nest 4 levels at most).
MAX_DEPTH = 64


def _depth_ok(text: str, where: str) -> None:
    """Refuse JSON nesting deeper than MAX_DEPTH before the recursive parser sees it."""
    depth = deepest = 0
    in_string = escaped = False
    for ch in text:
        if in_string:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == '"':
                in_string = False
        elif ch == '"':
            in_string = True
        elif ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif ch in "]}":
            depth -= 1
    if deepest > MAX_DEPTH:
        raise InputError(
            f"{where}: nested {deepest} levels deep, more than the {MAX_DEPTH} allowed; "
            "this is not a bikeid file"
        )


def _no_duplicates(pairs: list[tuple[str, Any]], where: str) -> dict:
    out: dict = {}
    for key, value in pairs:
        if key in out:
            raise InputError(f"{where}: key {key!r} appears twice; keep one")
        out[key] = value
    return out


def loads_json(text: str, where: str) -> Any:
    """Parse JSON strictly: no duplicate keys, no NaN/Infinity, bounded nesting.

    Parameters
    ----------
    text : str
        The JSON text.
    where : str
        Names the source in messages (e.g. ``"model file 'm.json'"``).

    Returns
    -------
    object
        The parsed value.

    Raises
    ------
    InputError
        If the text is not valid JSON (line and column named), repeats a key in an
        object, holds NaN or Infinity, or nests deeper than :data:`MAX_DEPTH`.
    """
    _depth_ok(text, where)

    def constant(name: str) -> None:
        raise InputError(f"{where}: {name} is not a number JSON allows; give a finite value")

    try:
        return json.loads(
            text,
            object_pairs_hook=lambda pairs: _no_duplicates(pairs, where),
            parse_constant=constant,
        )
    except json.JSONDecodeError as exc:
        raise InputError(
            f"{where} is not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}"
        ) from None
    except RecursionError:
        raise InputError(f"{where}: nested too deeply to read") from None


def loads_yaml(text: str, where: str) -> Any:
    """Parse YAML (safe loader) strictly: no duplicate keys, bounded nesting.

    Parameters
    ----------
    text : str
        The YAML text.
    where : str
        Names the source in messages.

    Returns
    -------
    object
        The parsed value.

    Raises
    ------
    InputError
        If the text is not valid YAML, repeats a key in a mapping, or nests deeper than
        :data:`MAX_DEPTH` (flow or block style).
    """
    import yaml

    class Loader(yaml.SafeLoader):
        pass

    def mapping(loader: yaml.SafeLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
        keys: set = set()
        for key_node, _ in node.value:
            key = loader.construct_object(key_node, deep=True)
            try:
                hash(key)
            except TypeError:
                mark = key_node.start_mark
                raise InputError(
                    f"{where}: line {mark.line + 1}: a mapping key must be a name or a number, "
                    f"got a {type(key).__name__}"
                ) from None
            if key in keys:
                mark = key_node.start_mark
                raise InputError(
                    f"{where}: key {key!r} appears twice (line {mark.line + 1}); keep one"
                )
            keys.add(key)
        return loader.construct_mapping(node, deep=deep)

    Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, mapping)
    try:
        _yaml_depth_ok(yaml, text, where)
        loader = Loader(text)
        try:
            node = loader.get_single_node()
            if node is not None and _node_depth(node) > MAX_DEPTH:
                raise InputError(
                    f"{where}: nested more than {MAX_DEPTH} levels deep; this is not a bikeid file"
                )
            return None if node is None else loader.construct_document(node)
        finally:
            loader.dispose()
    except yaml.YAMLError as exc:
        first = str(exc).strip().splitlines()
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1} column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or (first[0] if first else "syntax error")
        raise InputError(f"{where} is not valid YAML: {problem}{at}") from None
    except RecursionError:
        raise InputError(f"{where}: nested too deeply to read") from None


def _yaml_depth_ok(yaml: Any, text: str, where: str) -> None:
    """Refuse YAML nesting deeper than MAX_DEPTH while parsing, before the tree is composed.

    The event stream stops at the first collection too deep: PyYAML's scanner and composer
    are quadratic in the nesting (5,000 nested flow sequences took ~2 s to compose only to be
    refused), so a hostile file is refused in milliseconds.
    """
    depth = 0
    for event in yaml.parse(text, Loader=yaml.SafeLoader):
        if isinstance(event, (yaml.SequenceStartEvent, yaml.MappingStartEvent)):
            depth += 1
            if depth > MAX_DEPTH:
                raise InputError(
                    f"{where}: nested more than {MAX_DEPTH} levels deep; this is not a bikeid file"
                )
        elif isinstance(event, (yaml.SequenceEndEvent, yaml.MappingEndEvent)):
            depth -= 1


def _node_depth(node: Any) -> int:
    """Nesting depth of a composed YAML node, iteratively (no recursion limit)."""
    deepest, stack, seen = 0, [(node, 1)], set()
    while stack:
        n, d = stack.pop()
        if id(n) in seen:  # an alias: already counted
            continue
        seen.add(id(n))
        deepest = max(deepest, d)
        if d > MAX_DEPTH:
            return d
        if isinstance(n.value, list):
            for item in n.value:
                if isinstance(item, tuple):  # mapping: (key, value)
                    stack.extend((x, d + 1) for x in item)
                else:
                    stack.append((item, d + 1))
    return deepest


def to_jsonable(obj: Any) -> Any:
    """numpy arrays, complex numbers and nested containers to plain JSON types.

    Complex numbers become ``{"re": x, "im": y}``; NaN/inf become ``null``; an object with
    an ``as_dict`` method becomes that dict.

    Parameters
    ----------
    obj : Any
        The value to convert.

    Returns
    -------
    Any
        The same structure in dicts, lists, str, int, float, bool and None.
    """
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (complex, np.complexfloating)):
        return {"re": to_jsonable(float(obj.real)), "im": to_jsonable(float(obj.imag))}
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if callable(getattr(obj, "as_dict", None)):  # e.g. NominalUncertainty
        return to_jsonable(obj.as_dict())
    return obj


def dump_json(obj: Any) -> str:
    """``obj`` as indented JSON text, through :func:`to_jsonable`.

    Parameters
    ----------
    obj : Any
        Nested dicts, lists, numpy arrays and scalars, complex numbers.

    Returns
    -------
    str
        The JSON text (2-space indent).
    """
    return json.dumps(to_jsonable(obj), indent=2)
