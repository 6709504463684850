"""One camera image per distinct condition of a frame, shared by the sequences that ask for it.

A render feeds several sequences; some of them are the same condition under another name
(the article's ``depth_1m`` is the turbidity experiment's ``mild`` water at the same 1 m
light depth). When a sequence's image is a deterministic function of the frame's passes
and its processing -- no random draws (no shot/read or 8-bit noise, no particles) and no
state carried between frames (no auto-exposure) -- two sequences whose processing is equal
up to the random seed get the same uint8 image: it is made once per frame and copied.
Anything else is composed as before. Parts of the image that do not depend on the water
(the caustics' geometry and deposits) are kept per frame for every sequence that sees the
frame's own passes (:meth:`FrameShare.memo`), noise or not. A sequence with particles sees
passes of its own, but its caustics are the frame's, made from the frame's own passes
(:meth:`FrameShare.frame_memo`, :data:`CLEAN`) and not applied where a particle hides the
surface.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

#: Key of the frame's own (clean) passes in its memo: what a sequence with particles builds the
#: frame's caustics from (``compose._world``).
CLEAN = "clean_passes"


def share_key(state) -> str | None:
    """Key of a sequence whose image depends only on the frame and its processing
    (``compose.SequenceState``), or None when it draws random numbers or carries state."""
    cam = state.camera
    if (
        state.field is not None
        or state.auto_exposure is not None
        or cam.noise
        or cam.noise_std > 0
        or state.post.occlusion is not None
    ):
        return None
    return state.post.model_dump_json(exclude={"seed"}) + repr(cam)


class FrameShare:
    """Camera images of the current frame by :func:`share_key`; ``begin`` each frame."""

    def __init__(self):
        self._passes = None
        self._images: dict[str, np.ndarray] = {}
        self._memo: dict = {}
        self.hits = 0

    def begin(self, passes: dict) -> None:
        """A new frame's clean passes (kept referenced: identity stays valid)."""
        self._passes = passes
        self._images = {}
        self._memo = {CLEAN: passes}

    def memo(self, seen: dict) -> dict:
        """The frame's dict of parts of an image that do not depend on the water (caustic
        geometry, the surface's wave geometry) when ``seen`` is the frame's own passes; a
        fresh dict otherwise (particles: the sequence sees passes of its own)."""
        return self._memo if seen is self._passes else {}

    def frame_memo(self) -> dict:
        """The frame's dict of water-independent parts whatever passes a sequence sees (its
        :data:`CLEAN` entry: the frame's own passes), for a sequence with particles: it reads and
        adds only parts made from the frame's own passes (``compose._world``)."""
        return self._memo

    def image(self, state, seen: dict, make: Callable[[], np.ndarray]) -> np.ndarray:
        """The image ``make()`` returns for ``state`` on ``seen`` (the frame's passes as the
        sequence sees them), made once per frame and key; a copy on a repeat."""
        key = share_key(state) if seen is self._passes else None
        if key is None:
            return make()
        if key in self._images:
            self.hits += 1
            state.exposure_s = state.camera.exposure_s
            return self._images[key].copy()
        img = self._images[key] = make()
        return img
