"""An impaired network between the simulated PLC and its peers: loss, duplication, reordering,
corruption, delay and jitter, applied to datagrams in each direction.
"""

from __future__ import annotations

import heapq
import math
import random
from collections import Counter
from dataclasses import dataclass


@dataclass
class Impairments:
    """What the simulated network does to each datagram (both directions)."""

    loss: float = 0.0  # probability a datagram is dropped
    dup: float = 0.0  # probability it is delivered twice
    reorder: float = 0.0  # probability it is held back so later ones overtake it
    corrupt: float = 0.0  # probability a copy has 1-3 random bytes flipped
    delay: float = 0.0  # s, latency added to every datagram
    jitter: float = 0.0  # s, uniform extra latency
    reorder_delay: float = 0.02  # s, longest extra hold of a reordered datagram
    seed: int | None = None

    @property
    def active(self) -> bool:
        return any((self.loss, self.dup, self.reorder, self.corrupt, self.delay, self.jitter))

    def check(self) -> None:
        for name in ("loss", "dup", "reorder", "corrupt"):
            v = getattr(self, name)
            if not 0.0 <= v < 1.0:
                raise ValueError(f"{name} must be a probability in [0, 1), got {v}")
        for name in ("delay", "jitter", "reorder_delay"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must not be negative")




class LossyNetwork:
    """Delivers datagrams through the impairments, in release-time order."""

    def __init__(self, imp: Impairments):
        imp.check()
        self.imp = imp
        self.rng = random.Random(imp.seed)
        self.heap: list = []
        self.n = 0
        self.stats = Counter()

    def schedule(self, now: float, payload: bytes, item) -> None:
        imp, rng = self.imp, self.rng
        if not imp.active:
            heapq.heappush(self.heap, (now, self.n, payload, item))
            self.n += 1
            return
        if rng.random() < imp.loss:
            self.stats["lost"] += 1
            return
        copies = 2 if rng.random() < imp.dup else 1
        self.stats["duplicated"] += copies - 1
        for _ in range(copies):
            data = payload
            if rng.random() < imp.corrupt:
                buf = bytearray(data)
                for _ in range(rng.randint(1, 3)):
                    buf[rng.randrange(len(buf))] ^= 1 << rng.randrange(8)
                data = bytes(buf)
                self.stats["corrupted"] += 1
            t = now + imp.delay + imp.jitter * rng.random()
            if rng.random() < imp.reorder:
                t += imp.reorder_delay * (0.2 + 0.8 * rng.random())
                self.stats["reordered"] += 1
            heapq.heappush(self.heap, (t, self.n, data, item))
            self.n += 1

    def due(self, now: float):
        while self.heap and self.heap[0][0] <= now:
            _, _, data, item = heapq.heappop(self.heap)
            yield data, item

    def next_time(self) -> float:
        return self.heap[0][0] if self.heap else math.inf
