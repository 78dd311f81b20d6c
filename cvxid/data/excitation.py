r"""Excitation signals for simulated experiments, described by data (never by code).

An input is a sum of components, each a mapping with a ``kind``:

=================  ===================================================================
``sine``           :math:`A \sin(\omega t + \varphi)` — keys ``amplitude``, ``omega`` (rad/s), ``phase``
``quadratic_chirp`` :math:`A \sin(\kappa t^2)` — keys ``amplitude``, ``rate`` (:math:`\kappa`, rad/s²)
``square``         :math:`A\,\operatorname{sign}\sin(2\pi F t)` — keys ``amplitude``, ``frequency`` (Hz)
``constant``       :math:`A` — key ``amplitude``
=================  ===================================================================

The paper's training force :math:`10\sin 4t + 40\sin 4t^2` is
``[{kind = "sine", amplitude = 10, omega = 4}, {kind = "quadratic_chirp", amplitude = 40, rate = 4}]``.
"""

from __future__ import annotations

from typing import Callable, Mapping, Sequence

import numpy as np

from cvxid.errors import CvxidError

_KINDS: dict[str, tuple[tuple[str, ...], Callable]] = {
    "sine": (("amplitude", "omega", "phase"), lambda t, a, w, p=0.0: a * np.sin(w * t + p)),
    "quadratic_chirp": (("amplitude", "rate"), lambda t, a, k: a * np.sin(k * t * t)),
    "square": (("amplitude", "frequency"), lambda t, a, fr: a * np.where(np.sin(2 * np.pi * fr * t) >= 0, 1.0, -1.0)),
    "constant": (("amplitude",), lambda t, a: a * np.ones_like(t)),
}


def component(spec: Mapping, where: str = "input") -> Callable[[np.ndarray], np.ndarray]:
    """One component, checked: unknown kinds and keys are errors that name the fix."""
    spec = dict(spec)
    kind = spec.pop("kind", None)
    if kind not in _KINDS:
        raise CvxidError(f"{where}: kind must be one of {', '.join(_KINDS)}, got {kind!r}")
    keys, func = _KINDS[kind]
    unknown = set(spec) - set(keys)
    if unknown:
        raise CvxidError(f"{where}: '{kind}' takes keys {', '.join(keys)}; unknown: {', '.join(sorted(unknown))}")
    required = [k for k in keys if k != "phase"]
    missing = [k for k in required if k not in spec]
    if missing:
        raise CvxidError(f"{where}: '{kind}' needs {', '.join(missing)}")
    try:
        args = [float(spec[k]) for k in keys if k in spec]
    except (TypeError, ValueError):
        raise CvxidError(f"{where}: the values of '{kind}' must be numbers") from None
    if not all(np.isfinite(args)):
        raise CvxidError(f"{where}: the values of '{kind}' must be finite")
    return lambda t: func(np.asarray(t, dtype=float), *args)


def excitation(components: Sequence[Mapping], where: str = "input") -> Callable[[np.ndarray], np.ndarray]:
    """The sum of the described components, as a function of time."""
    if not components:
        raise CvxidError(f"{where}: give at least one component")
    parts = [component(c, f"{where}[{i}]") for i, c in enumerate(components)]
    return lambda t: sum(p(t) for p in parts)
