"""Scores of one discovery against the term a generator injected (the rate benchmarks').

:func:`score_discovery` reads the ``terms`` list of ``bikeid measured discover --json`` (or
:meth:`bikeid.ident.effects.discovery.Discovery.as_dict`) and says whether the injected term
was found, whether its coefficient lands within 35 % and whether its interval covers the
truth; with no injected term it says whether anything was kept (a false discovery).
"""

from __future__ import annotations

__all__ = ["WITHIN", "score_discovery"]

#: Relative tolerance of ``within35`` on the coefficient.
WITHIN = 0.35


def _label(d: dict) -> str:
    return f"{d['equation']}: {d['term']}"


def score_discovery(kept: list[dict], term: str | None, coefficient: float = 0.0) -> dict:
    """How a discovery's kept terms answer an injected term.

    Parameters
    ----------
    kept : list of dict
        The discovery's ``terms`` (each with ``equation``, ``term``, ``coefficient``,
        ``interval`` and ``indistinguishable``, a list of the same fields).
    term : str or None
        The injected term, ``"equation: term"`` as the dictionary labels it (``"roll:
        phidot"``); None when nothing was injected.
    coefficient : float, optional
        Its true coefficient [the term's SI unit].

    Returns
    -------
    dict
        ``kept`` (labels of the kept terms); with no term ``false_discovery`` (anything
        kept); otherwise ``found`` (exactly one term kept, the injected one or one whose
        ``indistinguishable`` set holds it), ``direct`` (the injected term itself kept,
        nothing extra), ``within35`` (found and its coefficient within :data:`WITHIN` of the
        truth), ``covers`` (found and its 95 % interval covers the truth), ``estimate`` and
        ``interval`` (the injected term's, kept or from the set; None when absent) and
        ``wrong`` (a kept term is neither the injected one nor holds it in its set).
    """
    labels = [_label(d) for d in kept]
    row: dict = {"kept": labels}
    if term is None:
        row["false_discovery"] = bool(kept)
        return row
    want = term.replace(" ", "")
    hit, holder = None, None
    for d in kept:
        for y in (d, *d.get("indistinguishable", ())):
            if _label(y).replace(" ", "") == want:
                hit, holder = y, d
    alone = len(kept) == 1
    found = hit is not None and alone
    c = float(coefficient)
    row.update(
        found=found,
        direct=alone and labels[0].replace(" ", "") == want,
        within35=hit is not None and abs(hit["coefficient"] - c) <= WITHIN * abs(c),
        covers=hit is not None and hit["interval"][0] <= c <= hit["interval"][1],
        estimate=None if hit is None else hit["coefficient"],
        interval=None if hit is None else list(hit["interval"]),
        wrong=any(d is not holder for d in kept),
    )
    return row
