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


def copied_generator(rng: np.random.Generator) -> np.random.Generator:
    """An independent generator in ``rng``'s state (the same draws from here on): what
    ``copy.deepcopy`` gives, at a third of its cost (it pickles the generator)."""
    bits = type(rng.bit_generator)(0)
    bits.state = rng.bit_generator.state
    return np.random.Generator(bits)
