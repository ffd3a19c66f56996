"""Normal draws of ``numpy.random.default_rng([seed, stream, k])`` for consecutive ``k``, fast.

The sensor draws its noise for sample ``k`` from ``default_rng([seed, stream, k])``: a pure
function of the sample index, so a seed gives one run whatever reads the sensor when. Building
that generator costs about 35 us (a ``SeedSequence``, then ``PCG64`` hashes it again), which the
sensor pays at each of its 100 samples a second. :class:`SeededNormals` gives the same numbers,
bit for bit, from a reused generator: it hashes the seed words of a block of consecutive ``k``
at once (NumPy's ``SeedSequence`` mixing, vectorised over the block) and sets the reused
``PCG64`` to the state NumPy's seeding would give (``pcg64_set_seed``). NumPy keeps both
algorithms fixed (its stream-compatibility policy for ``SeedSequence`` and ``PCG64``); a test
compares the draws with ``default_rng`` for many ``k``. Anything outside 32-bit words (a seed
or ``k`` that NumPy would split into more words) goes through ``default_rng`` itself.
"""

from __future__ import annotations

import threading

import numpy as np

_M32 = 0xFFFFFFFF
_INIT_A, _MULT_A = 0x43B0D7E5, 0x931E8875  # SeedSequence's entropy hashing
_INIT_B, _MULT_B = 0x8B51F9DD, 0x58F38DED  # SeedSequence.generate_state's hashing
_MIX_L, _MIX_R = 0xCA01F9DD, 0x4973F715
_POOL = 4  # SeedSequence's pool size (32-bit words)
_PCG_MULT = (2549297995355413924 << 64) + 4865540595714422341  # PCG64's 128-bit multiplier
_M128 = (1 << 128) - 1
_BLOCK = 512
"""Sample indices hashed together (a block covers 5 s of a 100 Hz sensor)."""


def _hashmix(value: np.ndarray, h: int) -> tuple[np.ndarray, int]:
    value = (value ^ np.uint64(h)) & np.uint64(_M32)
    h = (h * _MULT_A) & _M32
    value = (value * np.uint64(h)) & np.uint64(_M32)
    return value ^ (value >> np.uint64(16)), h


def _mix(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    r = (np.uint64(_MIX_L) * x - np.uint64(_MIX_R) * y) & np.uint64(_M32)
    return r ^ (r >> np.uint64(16))


def seed_state_words(words: list[int], last: np.ndarray) -> np.ndarray:
    """``SeedSequence([*words, k]).generate_state(4, np.uint64)`` for each ``k`` in ``last``
    (every word and ``k`` in [0, 2**32)): an (N, 4) uint64 array."""
    last = np.asarray(last, dtype=np.uint64)
    entropy = [np.full(last.size, w, dtype=np.uint64) for w in words] + [last]
    if len(entropy) > _POOL:
        raise ValueError(f"seed_state_words: at most {_POOL} entropy words, got {len(entropy)}")
    h = _INIT_A
    pool = []
    for i in range(_POOL):
        v, h = _hashmix(entropy[i] if i < len(entropy) else np.zeros(last.size, np.uint64), h)
        pool.append(v)
    for i_src in range(_POOL):
        for i_dst in range(_POOL):
            if i_src != i_dst:
                hashed, h = _hashmix(pool[i_src], h)
                pool[i_dst] = _mix(pool[i_dst], hashed)
    h = _INIT_B
    out = np.empty((last.size, 2 * _POOL), dtype=np.uint32)
    for i in range(2 * _POOL):
        v = pool[i % _POOL] ^ np.uint64(h)
        h = (h * _MULT_B) & _M32
        v = (v * np.uint64(h)) & np.uint64(_M32)
        out[:, i] = v ^ (v >> np.uint64(16))
    return out.view("<u8")


def pcg64_state(words: np.ndarray) -> dict:
    """The ``PCG64.state`` that ``PCG64(seed_sequence)`` sets from the sequence's four 64-bit
    state words ``words``: 128-bit seed and increment, then NumPy's ``pcg64_srandom_r``."""
    seed = (int(words[0]) << 64) | int(words[1])
    inc = ((((int(words[2]) << 64) | int(words[3])) << 1) | 1) & _M128
    state = (((inc + seed) & _M128) * _PCG_MULT + inc) & _M128
    return {
        "bit_generator": "PCG64",
        "state": {"state": state, "inc": inc},
        "has_uint32": 0,
        "uinteger": 0,
    }


class SeededNormals:
    """``normals(k, n)`` == ``np.random.default_rng([seed, stream, k]).standard_normal(n)``."""

    def __init__(self, seed: int, stream: int) -> None:
        self.seed, self.stream = int(seed), int(stream)
        self._fast = 0 <= self.seed <= _M32 and 0 <= self.stream <= _M32
        self._bits = np.random.PCG64(0)
        self._generator = np.random.Generator(self._bits)
        self._start = -1  # first k of the hashed block
        self._words = np.zeros((0, 4), dtype=np.uint64)
        self._lock = threading.Lock()  # one reused generator: one caller at a time

    def normals(self, k: int, n: int) -> np.ndarray:
        """The first ``n`` standard normal draws of sample ``k``'s generator."""
        k = int(k)
        if not (self._fast and 0 <= k <= _M32):
            return np.random.default_rng([self.seed, self.stream, k]).standard_normal(n)
        with self._lock:
            if not 0 <= k - self._start < len(self._words):
                self._start = k
                last = np.arange(k, min(k + _BLOCK, _M32 + 1), dtype=np.uint64)
                self._words = seed_state_words([self.seed, self.stream], last)
            self._bits.state = pcg64_state(self._words[k - self._start])
            return self._generator.standard_normal(n)
