"""Random generators re-seeded in place (the simulator's per-batch noise streams).

``Reseedable().seed(entropy)`` is a generator with the stream of ``np.random.default_rng(entropy)``
for a sequence of non-negative ints: numpy's SeedSequence (pool of 4 words; NEP 19 keeps its
streams stable) and PCG64's seeding from it, in Python ints, set as the state of one PCG64 kept
from call to call. Building a SeedSequence, a PCG64 and a Generator per batch costs ~30 us in
the simulator's loop, where their many small steps run with cold caches.
"""

from __future__ import annotations

import numba
import numpy as np

_M32 = 0xFFFFFFFF
_INIT_A, _MULT_A, _INIT_B, _MULT_B = 0x43B0D7E5, 0x931E8875, 0x8B51F9DD, 0x58F38DED
_MIX_L, _MIX_R = 0xCA01F9DD, 0x4973F715
_PCG_MULT = (2549297995355413924 << 64) | 4865540595714422341  # PCG_DEFAULT_MULTIPLIER_128
_M128 = (1 << 128) - 1


def _words(entropy) -> list[int]:
    """SeedSequence's uint32 words of a sequence of non-negative ints (little-endian, 0 -> [0])."""
    out = []
    for n in entropy:
        n = int(n)
        if n < 0:
            raise ValueError("expected non-negative integer")
        out.append(n & _M32)
        n >>= 32
        while n:
            out.append(n & _M32)
            n >>= 32
    return out


@numba.njit(cache=True)
def _state_words(words):
    """numpy ``SeedSequence(words).generate_state(8)`` (uint32 words, as uint64) for a pool of 4."""
    m32, shift = np.uint64(0xFFFFFFFF), np.uint64(16)
    mult_a, mult_b = np.uint64(_MULT_A), np.uint64(_MULT_B)
    mix_l, mix_r = np.uint64(_MIX_L), np.uint64(_MIX_R)
    h = np.uint64(_INIT_A)
    pool = np.zeros(4, np.uint64)
    for i in range(4 + 12 + 4 * max(len(words) - 4, 0)):
        # hashmix of the next word: entropy words into the pool, then every pool word into every
        # other, then the remaining entropy words into every pool word
        if i < 4:
            value = words[i] if i < len(words) else np.uint64(0)
        elif i < 16:
            src, dst = (i - 4) // 3, (i - 4) % 3
            dst += dst >= src
            value = pool[src]
        else:
            dst, value = (i - 16) % 4, words[4 + (i - 16) // 4]
        value ^= h
        h = (h * mult_a) & m32
        value = (value * h) & m32
        value ^= value >> shift
        if i < 4:
            pool[i] = value
        else:  # mix
            r = (mix_l * pool[dst] - mix_r * value) & m32
            pool[dst] = r ^ (r >> shift)
    h = np.uint64(_INIT_B)
    out = np.empty(8, np.uint64)
    for i in range(8):
        value = pool[i % 4] ^ h
        h = (h * mult_b) & m32
        value = (value * h) & m32
        out[i] = value ^ (value >> shift)
    return out


def pcg64_state(entropy) -> tuple[int, int]:
    """PCG64 (state, increment) of ``np.random.default_rng(entropy)``."""
    w = _state_words(np.array(_words(entropy), np.uint64)).tolist()
    seed = (w[1] << 96) | (w[0] << 64) | (w[3] << 32) | w[2]
    inc = (((w[5] << 96) | (w[4] << 64) | (w[7] << 32) | w[6]) << 1 | 1) & _M128
    return ((inc + seed) * _PCG_MULT + inc) & _M128, inc  # pcg_setseq_128_srandom_r: two steps from 0


class Reseedable:
    """One PCG64 and its Generator; :meth:`seed` re-seeds them in place."""

    def __init__(self) -> None:
        self._bits = np.random.PCG64(0)
        self._generator = np.random.Generator(self._bits)

    def seed(self, entropy) -> np.random.Generator:
        """The generator with the stream of ``np.random.default_rng(entropy)``, until the next call."""
        state, inc = pcg64_state(entropy)
        self._bits.state = {"bit_generator": "PCG64", "state": {"state": state, "inc": inc}, "has_uint32": 0,
                            "uinteger": 0}  # fmt: skip
        return self._generator
