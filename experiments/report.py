"""Markdown report building: tables of paper | identified | truth, figures, and the
machine-readable ``summary.json`` written next to ``report.md`` (both atomically)."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bikeid.dataset.files import atomic_write_text
from bikeid.sim.textformats import to_jsonable

__all__ = ["Report", "fmt", "fmt_complex", "write"]


def fmt(x: Any, digits: int = 4) -> str:
    """A number for a table: ``digits`` significant figures; '-' for None/NaN.

    Parameters
    ----------
    x : object
        A real or complex number (complex as :func:`fmt_complex`), a string (returned
        as is) or None.
    digits : int, optional
        Significant figures.

    Returns
    -------
    str
        The formatted number (``"0"`` for zero; ``"-"`` for None, NaN or infinity).

    Raises
    ------
    TypeError, ValueError
        If ``x`` is none of these and does not convert to float.
    """
    if x is None:
        return "-"
    if isinstance(x, (complex, np.complexfloating)):
        return fmt_complex(x, digits)
    if isinstance(x, str):
        return x
    x = float(x)
    if not math.isfinite(x):
        return "-"
    if x == 0:
        return "0"
    return f"{x:.{digits}g}"


def fmt_complex(z: complex, digits: int = 4) -> str:
    """``a ± bi`` style for one member of a conjugate pair, plain real otherwise.

    Parameters
    ----------
    z : complex
        The number.
    digits : int, optional
        Significant figures of the real and imaginary parts.

    Returns
    -------
    str
        ``"a + bi"`` or ``"a - bi"`` (|imaginary part| below 1e-9: the real part alone).
    """
    z = complex(z)
    if abs(z.imag) < 1e-9:
        return fmt(z.real, digits)
    sign = "+" if z.imag >= 0 else "-"
    return f"{fmt(z.real, digits)} {sign} {fmt(abs(z.imag), digits)}i"


class Report:
    """An ordered list of markdown blocks.

    Parameters
    ----------
    title : str
        The report's level-1 heading.

    Attributes
    ----------
    blocks : list of str
        The markdown blocks in order, the title first.
    """

    def __init__(self, title: str) -> None:
        self.blocks: list[str] = [f"# {title}\n"]

    def heading(self, text: str, level: int = 2) -> None:
        """Append a heading.

        Parameters
        ----------
        text : str
            Heading text.
        level : int, optional
            Markdown level (number of ``#``).
        """
        self.blocks.append(f"{'#' * level} {text}\n")

    def para(self, text: str) -> None:
        """Append a paragraph.

        Parameters
        ----------
        text : str
            Markdown text (surrounding whitespace stripped).
        """
        self.blocks.append(text.strip() + "\n")

    def table(self, headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
        """Append a markdown table.

        Parameters
        ----------
        headers : sequence of str
            Column headings.
        rows : sequence of sequence
            Cells; numbers are formatted by :func:`fmt`, ``|`` and newlines escaped.
        """
        def cell(x):
            return str(x if isinstance(x, str) else fmt(x)).replace("|", "\\|").replace("\n", " ")

        lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
        lines += ["| " + " | ".join(cell(x) for x in r) + " |" for r in rows]
        self.blocks.append("\n".join(lines) + "\n")

    def figure(self, path: str, caption: str) -> None:
        """Append an image with its caption.

        Parameters
        ----------
        path : str
            Image path, relative to the report.
        caption : str
            Caption (also the alt text).
        """
        self.blocks.append(f"![{caption}]({path})\n\n*{caption}* (`{path}`)\n")

    def markdown(self) -> str:
        """The report as one markdown document.

        Returns
        -------
        str
            The blocks joined by blank lines.
        """
        return "\n".join(self.blocks)


def _strip_private(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _strip_private(v) for k, v in obj.items() if not str(k).startswith("_")}
    if isinstance(obj, (list, tuple)):
        return [_strip_private(v) for v in obj]
    return obj


def write(out: Path, report: Report, summary: dict[str, Any]) -> tuple[Path, Path]:
    """Write ``report.md`` and ``summary.json`` (keys starting with '_' are left out; complex
    numbers become {"re", "im"}; NaN becomes null).

    Parameters
    ----------
    out : Path
        Existing output folder.
    report : Report
        The report.
    summary : dict
        The numbers behind it.

    Returns
    -------
    md : Path
        ``out/report.md``.
    js : Path
        ``out/summary.json``.

    Raises
    ------
    ValueError
        If a target path is unsafe to replace (a symlink or device; atomic writes).
    """
    out = Path(out)
    md, js = out / "report.md", out / "summary.json"
    atomic_write_text(md, report.markdown())
    atomic_write_text(js, json.dumps(to_jsonable(_strip_private(summary)), indent=1))
    return md, js
