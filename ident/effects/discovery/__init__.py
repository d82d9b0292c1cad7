"""Discovery: name a term the equations of motion lack, from the residual of the decays.

Front door:

- :func:`discover`: the forward selection of dictionary terms on the closure error, with a
  familywise error rate, coefficients and intervals from that error, indistinguishable
  sets and the held-out before/after (:mod:`.search`).
- :func:`dictionary`: the terms of the roll and steer equations, generated from the effect
  laws' language, each with its SI unit and reading (:mod:`.dictionary`).
- :func:`injection_file`: dictionary terms with values as an effects file, so the
  project's generator can add any of them.
"""

from bikeid.ident.effects.discovery.dictionary import (
    Term,
    dictionary,
    injection_file,
    term_by_name,
)
from bikeid.ident.effects.discovery.search import Discovery, discover, window_error

__all__ = [
    "Discovery",
    "Term",
    "dictionary",
    "discover",
    "injection_file",
    "term_by_name",
    "window_error",
]
