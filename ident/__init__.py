"""Identification: Moore & Hubbard direct least squares, Chen & Dao canonical PEM.

- :mod:`ident.signals`: mean removal, zero-phase Butterworth, differentiation.
- :mod:`ident.direct`: ``identify`` (LS/IV on the canonical rows), ``vaf_moore``,
  ``vaf_variance``.
- :mod:`ident.canonical`: Chen & Dao's canonical form and speed parameterization.
- :mod:`ident.subspace`: PBSID (closed-loop safe) and PO-MOESP (open loop).
- :mod:`ident.pem`: ``fit`` (fixed speed) and ``fit_speed_model`` (speed-parameterized).
- :mod:`ident.validate`: ``compare``, ``resid``, ``goodness_of_fit``, poles, zeros.
"""

from .direct import DirectResult, identify, vaf_moore, vaf_variance
from .pem import CanonicalModel, SpeedCanonicalModel, fit, fit_speed_model

__all__ = [
    "CanonicalModel",
    "DirectResult",
    "SpeedCanonicalModel",
    "fit",
    "fit_speed_model",
    "identify",
    "vaf_moore",
    "vaf_variance",
]
