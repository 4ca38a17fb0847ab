# Copyright 2026 pmba_ros maintainers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""Files damaged as a disk, a copy or a killed writer damages them: for robustness checks.

:func:`damage_bytes` applies one kind of damage drawn at random: cut short, bits flipped, a
span zeroed or repeated, or a token a reader must refuse (``nan``, ``inf``, ``1e308``, a
byte that is not UTF-8) written into the text.
"""

from __future__ import annotations

import random

__all__ = ['DAMAGE_KINDS', 'damage_bytes']

DAMAGE_KINDS = ('cut', 'flip', 'zero', 'repeat', 'token')

TOKENS = (b'nan', b'inf', b'-1', b'1e308', b'0', b'x', b'99999999999999999999', b'\xa0')


def damage_bytes(data: bytes, rng: random.Random) -> bytes:
    """Return ``data`` (not empty) with one kind of damage of :data:`DAMAGE_KINDS`."""
    b = bytearray(data)
    kind = rng.choice(DAMAGE_KINDS)
    i = rng.randrange(len(b))
    if kind == 'cut':
        return bytes(b[:i])
    if kind == 'flip':
        for _ in range(rng.randint(1, 20)):
            k = rng.randrange(len(b))
            b[k] ^= 1 << rng.randrange(8)
        return bytes(b)
    if kind == 'zero':
        n = min(rng.randint(1, 200), len(b) - i)
        b[i:i + n] = bytes(n)
        return bytes(b)
    if kind == 'repeat':
        j = min(len(b), i + rng.randint(1, 300))
        return bytes(b[:j] + b[i:j] + b[j:])
    return bytes(b[:i] + rng.choice(TOKENS) + b[i + rng.randint(0, 5):])
