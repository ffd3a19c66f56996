"""The current frame's visit: which context's theta may be handed, every hold and confirmation
(no pydrake).

The camera's context id per sample is noisy in two ways, and the two errors cost differently:

* a **noise frame** (-1) inside a known terrain (motion blur, a shadow) or at the start of a new
  terrain. Less friction is acted on at once, so the first noise frame already hands the unknown
  value where that is lower than the context's (a new terrain met inside a bend gets the floor
  from its first frame). The visit is kept open for ``noise_hold_s``: where the last context has
  *less* friction than the unknown value it is kept meanwhile, and when its id comes back within
  the hold its theta is handed again at once (its visit was confirmed and noise alone does not
  end it).
* a **wrong id** for a few frames (a transition strip that looks like another terrain). A
  switch to a context with *more* friction is taken only once that context has been reported
  for ``confirm_s``: the first frame with its id at least ``confirm_s`` after its first one
  (noise frames in between do not reset the count; another context's id does). A switch to
  less friction is taken at once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

NOISE = -1


@dataclass
class VisitTracker:
    """The visit state; the :class:`pcvfe_drake.handing.handing.Handing` feeds it every sample.

    Attributes:
        noise_hold_s: how long [s] a noise spell keeps the visit open.
        confirm_s: how long [s] a context must be reported before a rise to it is taken.
    """

    noise_hold_s: float = 1.0
    confirm_s: float = 1.0
    current: int = NOISE
    """The latest sample's context id (-1: noise)."""
    last_known: int = NOISE
    """The latest context id other than noise."""
    last_known_time_s: float = -math.inf
    last_sample_time_s: float = -math.inf
    confirmed: int = NOISE
    """The context whose theta is handed as confirmed (-1: the unknown value)."""
    streak: int = NOISE
    """The latest context id reported (noise frames do not change it)."""
    streak_start_s: float = -math.inf
    """Time of the first sample of ``streak`` [s]."""

    def observe(self, t_s: float, ident: int) -> None:
        """One sample at ``t_s`` with context id ``ident`` (-1 noise). Non-finite times only set
        the current id."""
        self.current = ident if ident >= 0 else NOISE
        if not math.isfinite(t_s):
            return
        self.last_sample_time_s = t_s
        if ident >= 0:
            self.last_known, self.last_known_time_s = ident, t_s
            if ident != self.streak:
                self.streak, self.streak_start_s = ident, t_s
        visit = self.visit()
        if visit < 0:
            self.confirmed = NOISE
        elif ident == self.streak and t_s - self.streak_start_s >= self.confirm_s - 1e-9:
            self.confirmed = ident

    def visit(self) -> int:
        """The context being visited: the current one; during noise the last known one within
        ``noise_hold_s`` of its last sample; else -1 (unknown)."""
        if self.current >= 0:
            return self.current
        held = self.last_sample_time_s - self.last_known_time_s <= self.noise_hold_s
        return self.last_known if held else NOISE

    @property
    def in_noise(self) -> bool:
        """The latest frame is noise (the visit, if any, is held)."""
        return self.current < 0

    def pending(self, ident: int) -> bool:
        """True while ``ident`` is a context switched to but not confirmed yet."""
        return self.confirm_s > 0 and ident >= 0 and ident != self.confirmed
