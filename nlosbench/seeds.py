"""Seed derivation: every random draw gets a seed derived from (experiment seed, purpose, indices).

Seeds are 32-bit (Mitsuba's `mi.render` takes a UInt32) and come from a cryptographic hash, so
neighbouring inputs give unrelated seeds and no two purposes share a stream by accident.
"""
from __future__ import annotations

import hashlib


def derive(seed: int, purpose: str, *indices: int) -> int:
    """A 32-bit seed for (seed, purpose, *indices); deterministic across processes and platforms."""
    msg = f"{int(seed)}|{purpose}|" + ",".join(str(int(i)) for i in indices)
    return int.from_bytes(hashlib.blake2b(msg.encode(), digest_size=4).digest(), "little")
