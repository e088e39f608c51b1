"""Per-tick random generators without numpy's per-call set-up cost.

``TickGenerators.get(words)`` returns a generator in exactly the state of
``np.random.default_rng(words)`` (``words`` < 2^32 each): numpy's SeedSequence
hashing (pool of 4 uint32, numpy/random/bit_generator.pyx) runs in numba, the
PCG64 seeding (pcg64_set_seed: two steps of the 128-bit LCG) in Python integers,
and the state is set on a bit generator that is reused. A generator from ``get``
is valid until the next ``get`` on the same slot.
"""

from __future__ import annotations

import numba
import numpy as np

_INIT_A, _MULT_A, _INIT_B, _MULT_B = 0x43B0D7E5, 0x931E8875, 0x8B51F9DD, 0x58F38DED
_MIX_L, _MIX_R = 0xCA01F9DD, 0x4973F715
_PCG_MULT = 0x2360ED051FC65DA44385DF649FCCF645
_M128 = (1 << 128) - 1


@numba.njit(cache=True, nogil=True)
def _seed_words(entropy):
    """The 8 uint32 words (as 4 uint64) that ``SeedSequence(entropy).generate_state(4, np.uint64)`` gives."""
    mask = np.uint64(0xFFFFFFFF)
    pool = np.zeros(4, np.uint64)
    h = np.uint64(_INIT_A)

    def hashmix(value, h):
        value = (value ^ h) & mask
        h = (h * np.uint64(_MULT_A)) & mask
        value = (value * h) & mask
        return value ^ (value >> np.uint64(16)), h

    def mix(x, y):
        r = (np.uint64(_MIX_L) * x - np.uint64(_MIX_R) * y) & mask
        return r ^ (r >> np.uint64(16))

    for i in range(4):
        pool[i], h = hashmix(np.uint64(entropy[i]) if i < len(entropy) else np.uint64(0), h)
    for i_src in range(4):
        for i_dst in range(4):
            if i_src != i_dst:
                v, h = hashmix(pool[i_src], h)
                pool[i_dst] = mix(pool[i_dst], v)
    for i_src in range(4, len(entropy)):
        for i_dst in range(4):
            v, h = hashmix(np.uint64(entropy[i_src]), h)
            pool[i_dst] = mix(pool[i_dst], v)
    out = np.zeros(4, np.uint64)
    hb = np.uint64(_INIT_B)
    for i in range(8):
        d = (pool[i % 4] ^ hb) & mask
        hb = (hb * np.uint64(_MULT_B)) & mask
        d = (d * hb) & mask
        d ^= d >> np.uint64(16)
        out[i // 2] |= d << np.uint64(32 * (i % 2))  # little-endian pairs
    return out


class TickGenerators:
    """Reusable generators, one per ``slot``, reseeded like ``np.random.default_rng(words)``."""

    def __init__(self, slots: int = 2) -> None:
        self._bits = [np.random.PCG64(0) for _ in range(slots)]
        self._gens = [np.random.Generator(b) for b in self._bits]

    def get(self, words, slot: int = 0) -> np.random.Generator:
        s0, s1, i0, i1 = (int(x) for x in _seed_words(np.array(words, np.uint64)))
        seed, inc = (s0 << 64) | s1, (((i0 << 64) | i1) << 1 | 1) & _M128
        state = ((inc + seed) * _PCG_MULT + inc) & _M128  # from 0: step (-> inc), add the seed, step
        self._bits[slot].state = {"bit_generator": "PCG64", "state": {"state": state, "inc": inc},
                                  "has_uint32": 0, "uinteger": 0}  # fmt: skip
        return self._gens[slot]
