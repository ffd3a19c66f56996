"""The cheap copies of abstract-state objects (pcvfe_drake.shallow_copy)."""

import copy
from dataclasses import dataclass, field

import numpy as np
import pytest

from pcvfe_drake.shallow_copy import CopiedOnDraw, shallow_copy


@dataclass
class _Mutable:
    a: int
    items: list = field(default_factory=list)


@dataclass(frozen=True)
class _Frozen:
    a: int
    b: tuple = ()


@pytest.mark.parametrize("obj", [_Mutable(1, [2]), _Frozen(3, (4,))])
def test_shallow_copy_is_what_copy_copy_gives(obj):
    other = shallow_copy(obj)
    assert other is not obj and type(other) is type(obj)
    assert other == copy.copy(obj)
    assert vars(other) == vars(obj) and all(vars(other)[k] is v for k, v in vars(obj).items())


def test_a_shallow_copy_takes_new_values_without_changing_the_original():
    obj = _Mutable(1)
    other = shallow_copy(obj)
    other.a = 5
    assert obj.a == 1


@pytest.mark.parametrize(
    "bits", [np.random.PCG64, np.random.PCG64DXSM, np.random.MT19937, np.random.Philox]
)
def test_a_copy_on_draw_draws_what_a_deep_copy_draws_and_is_independent(bits):
    rng = np.random.Generator(bits(7))
    rng.random(3)
    kept = CopiedOnDraw(rng)
    mine, theirs = copy.deepcopy(kept), copy.deepcopy(rng)
    of_copy = copy.deepcopy(mine)  # a copy of a copy that has not drawn yet
    rng.random(2)  # the original draws after the copies were taken: they do not see it
    drawn = mine.generator().random(5)
    assert np.array_equal(drawn, theirs.random(5))
    assert np.array_equal(of_copy.generator().random(5), drawn)
    assert mine.generator() is mine.generator()  # built once
    assert kept.generator() is rng
    after = copy.deepcopy(mine)  # a copy of one that drew continues from where it stopped
    assert np.array_equal(after.generator().random(2), mine.generator().random(2))
