"""Cheap copies for the objects a Drake context keeps in its abstract state.

Drake copies a system's abstract state twice per update event (into the event's scratch state
and back), and pydrake copies a Python value with ``copy.deepcopy``. The estimator's and the
clustering's states are updated 100 and 10 times a second, so their ``__deepcopy__`` methods
copy only what an update writes into and share the rest (read-only arrays, immutable records).
They build those copies from :func:`shallow_copy`.
"""

from __future__ import annotations

from typing import TypeVar

import numpy as np

T = TypeVar("T")


def shallow_copy(obj: T) -> T:
    """A new object of ``obj``'s class holding the same attribute values (not copied).

    What ``copy.copy`` gives for a class with a ``__dict__`` (plain classes and dataclasses,
    frozen or not, without ``__slots__``), without the pickling protocol ``copy.copy`` goes
    through.
    """
    other = object.__new__(type(obj))
    other.__dict__.update(obj.__dict__)
    return other


def _generator_in(kind: type, state: dict) -> np.random.Generator:
    """A generator of bit generator ``kind`` in ``state``: what ``copy.deepcopy`` of a
    generator gives, at a third of its cost (it pickles the generator)."""
    bits = kind(0)  # the seeding costs most of it (about 20 us)
    bits.state = state
    return np.random.Generator(bits)


class CopiedOnDraw:
    """A random generator whose copies are made when they first draw.

    Drake copies a system's abstract state twice per update and the copy that draws is at
    most one of them; a copy here keeps the generator's state (a dict of integers, about
    2 us to read) and builds the generator from it only when :meth:`generator` is asked for
    (about 20 us, most of it seeding). Every copy draws what ``copy.deepcopy`` of the
    generator would draw.
    """

    def __init__(self, rng: np.random.Generator) -> None:
        self._rng: np.random.Generator | None = rng
        self._kind = type(rng.bit_generator)
        self._state: dict | None = None

    def generator(self) -> np.random.Generator:
        """The generator itself (built from the kept state the first time)."""
        if self._rng is None:
            self._rng = _generator_in(self._kind, self._state)
            self._state = None
        return self._rng

    def __deepcopy__(self, memo) -> CopiedOnDraw:
        other = shallow_copy(self)
        if self._rng is not None:  # a fresh dict: later draws of this one do not change it
            other._rng, other._state = None, self._rng.bit_generator.state
        return other
