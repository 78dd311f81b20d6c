"""What a record's many fits share, computed once per record object.

A delay profile refits one record some 30 times and a stepwise search some 100: each fit
reads the same facts of the record that no parameter changes (where its simulation starts
and the measured past before it, its sub-steps, typical states and sizes, its initial
state).  :func:`remembered` keeps them beside the record object while it lives: keyed by
the object's identity, checked by a weak reference, so a record that is gone (and another
that takes its place in memory) never reads them.
"""

from __future__ import annotations

import threading
import weakref
from typing import Callable, Hashable, TypeVar

T = TypeVar("T")

_FACTS: dict[int, tuple[weakref.ref, dict]] = {}
_LOCK = threading.Lock()


def remembered(record: object, key: Hashable, compute: Callable[[], T]) -> T:
    """``compute()`` for ``record`` and ``key``, once while ``record`` lives (the value is
    shared: treat it as read-only)."""
    with _LOCK:
        entry = _FACTS.get(id(record))
        if entry is None or entry[0]() is not record:
            entry = _FACTS[id(record)] = (weakref.ref(record, _forget(id(record))), {})
        facts = entry[1]
        if key in facts:
            return facts[key]
    value = compute()  # (outside the lock: two threads may both compute it, and agree)
    with _LOCK:
        return facts.setdefault(key, value)


def _forget(identity: int) -> Callable[[weakref.ref], None]:
    def forget(reference: weakref.ref) -> None:
        with _LOCK:
            if identity in _FACTS and _FACTS[identity][0] is reference:
                del _FACTS[identity]
    return forget
