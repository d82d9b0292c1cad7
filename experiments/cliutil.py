"""Small helpers shared by the command modules: ranges, JSON output, bicycles.

``atomic_write_text`` is :func:`dataset.files.atomic_write_text` (re-exported for the
command modules)."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

from bikeid.dataset.files import atomic_write_text

__all__ = [
    "MAX_POINTS",
    "atomic_write_text",
    "dump_json",
    "parse_range",
    "to_jsonable",
]

#: Largest number of values a range may expand to.
MAX_POINTS = 1_000_000


def parse_range(text: str, name: str = "range", minimum: float | None = None) -> np.ndarray:
    """Parse ``start:stop:step`` (stop included, MATLAB style), ``a,b,c`` or one value."""
    text = text.strip()
    try:
        parts = [float(x) for x in text.split(":")] if ":" in text else None
        values = None if parts else np.array([float(x) for x in text.split(",") if x.strip()])
    except ValueError:
        raise ValueError(
            f"{name} {text!r} is not start:stop:step, a comma list or a number"
        ) from None
    if parts is not None:
        if len(parts) != 3 or not all(map(math.isfinite, parts)):
            raise ValueError(f"{name} {text!r}: use start:stop:step with three finite numbers")
        start, stop, step = parts
        if step <= 0 or stop < start:
            raise ValueError(f"{name} {text!r}: need start <= stop and step > 0")
        count = math.floor((stop - start) / step + 1e-9) + 1
        if count > MAX_POINTS:
            raise ValueError(
                f"{name} {text!r} has {count:.3g} values; at most {MAX_POINTS:,} "
                "(use a larger step)"
            )
        values = start + step * np.arange(int(count))
    if values.size == 0 or not np.all(np.isfinite(values)):
        raise ValueError(f"{name} {text!r} holds no finite values")
    if minimum is not None and values.min() < minimum:
        raise ValueError(f"{name} {text!r}: values must be >= {minimum}")
    return np.round(values, 12)


def to_jsonable(obj: Any) -> Any:
    """numpy arrays, complex numbers and nested containers to plain JSON types.

    Complex numbers become ``{"re": x, "im": y}``; NaN/inf become ``null``.
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
    return obj


def dump_json(obj: Any) -> str:
    return json.dumps(to_jsonable(obj), indent=2)
