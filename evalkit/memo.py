"""One localizer call per frame, shared: ``-l led -l qr -l hybrid`` runs LED and QR once.

The hybrid localizer runs its own LED and QR localizers; when the same localizers are
also evaluated on their own, every frame would be localized twice by each. This module
memoises ``localize`` per frame: a call is looked up by

    (localizer configuration, frame identity, the localizer's state that the result
     depends on)

and a hit returns a copy of the stored estimate and moves the caller's localizer to the
state the call would have left it in, so every localizer sees exactly the sequence of
estimates and states it would see alone (``tests/test_memo.py`` checks the hybrid's
rows against a run of the hybrid alone).

Only classes that opt in take part (the class itself defines ``memo_state`` and
``memo_apply``; subclasses do not inherit the opt-in, since they may keep more state):

* ``memo_state() -> bytes``: the part of the state the next result depends on
  (``b""`` for a stateless localizer);
* ``memo_after() -> object``: a snapshot of the state a call changes, taken before and
  after a real call; ``memo_apply(before, after, estimate)`` moves another instance as
  that call moved this one (on a hit).

The configuration is the registry spec and constructor parameters
(:func:`evalkit.registry.resolve` records them as ``memo_config``); anything wrapped
(preprocessing, isolation, external programs) has none and is never shared.
Frames are identified by (sequence id, frame index) within one evaluation process.
A replayed call's wall time is credited to the caller's ``ms`` (:meth:`FrameMemo.take_credit_ms`),
so runtime tables still read as if each localizer had run alone.
"""

from __future__ import annotations

import copy
import time
from typing import Any

import numpy as np


class FrameMemo:
    """Estimates of the current frame: (config, state) -> (estimate, state after)."""

    def __init__(self):
        self.frame: Any = None
        self._store: dict = {}
        self.hits = 0
        self.calls = 0
        self._credit_ms = 0.0

    def take_credit_ms(self) -> float:
        """Wall time (ms) of the real calls replayed since the last ask: the runner adds it
        to the caller's ``ms``, so a localizer's runtime reads as if it had run alone."""
        ms, self._credit_ms = self._credit_ms, 0.0
        return ms

    def begin(self, frame_key: Any) -> None:
        """Start a frame (``(sequence id, index)``): forget the previous frame's estimates."""
        if frame_key != self.frame:
            self.frame = frame_key
            self._store.clear()


def opted_in(obj: Any) -> bool:
    """True when ``obj``'s own class defines the memo hooks and it has a registry config."""
    cls = type(obj)
    return (
        "memo_state" in cls.__dict__ and "memo_apply" in cls.__dict__ and getattr(obj, "memo_config", None) is not None
    )


class SharedLocalizer:
    """Proxy of an opted-in localizer whose ``localize`` goes through a :class:`FrameMemo`;
    every other attribute (``reset``, ``set_roi_hint``, ``_marker``...) is the real one's."""

    def __init__(self, inner: Any, memo: FrameMemo):
        self.__dict__["inner"] = inner
        self.__dict__["memo"] = memo

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def __setattr__(self, name: str, value: Any) -> None:
        setattr(self.inner, name, value)

    def localize(self, image: np.ndarray) -> Any:
        memo, inner = self.memo, self.inner
        key = (inner.memo_config, inner.memo_state())
        hit = memo._store.get(key)
        memo.calls += 1
        if hit is not None:
            memo.hits += 1
            est, before, after, exc, ms = hit
            memo._credit_ms += ms
            inner.memo_apply(before, after, est)
            if exc is not None:
                raise exc
            return copy.deepcopy(est)
        before = inner.memo_after()
        t0 = time.perf_counter()
        try:
            est = inner.localize(image)
        except Exception as e:  # noqa: BLE001 - the same failure for every caller
            memo._store[key] = (None, before, inner.memo_after(), e, (time.perf_counter() - t0) * 1e3)
            raise
        memo._store[key] = (copy.deepcopy(est), before, inner.memo_after(), None, (time.perf_counter() - t0) * 1e3)
        return est


def share(localizers: list[tuple[str, Any]], memo: FrameMemo) -> list[tuple[str, Any]]:
    """The localizer list with every opted-in localizer, and the opted-in sub-localizers
    of composite ones (``subs``: the hybrid), routed through ``memo``. Nothing changes
    unless at least two opted-in localizers share a configuration."""
    found: list[tuple[Any, str | None, Any]] = []  # (owner, role or None, localizer)
    for _, loc in localizers:
        if opted_in(loc):
            found.append((None, None, loc))
        subs = getattr(loc, "subs", None)
        if isinstance(subs, dict):
            found += [(loc, role, sub) for role, sub in subs.items() if opted_in(sub)]
    configs = [f[2].memo_config for f in found]
    shared = {c for c in configs if configs.count(c) > 1}
    if not shared:
        return list(localizers)
    out = []
    for name, loc in localizers:
        if opted_in(loc) and loc.memo_config in shared:
            loc = SharedLocalizer(loc, memo)
        subs = getattr(loc, "subs", None)
        if isinstance(subs, dict):
            for role, sub in list(subs.items()):
                if opted_in(sub) and sub.memo_config in shared:
                    subs[role] = SharedLocalizer(sub, memo)
        out.append((name, loc))
    return out


def config_key(spec: str, params: dict) -> str:
    """A localizer's configuration as a string: spec and sorted parameters."""
    import json

    return spec + " " + json.dumps(params, sort_keys=True, default=repr)
