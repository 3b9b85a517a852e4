"""Brute-force reference of Steinhurst's hashed queues (spec seed-001 §2.7.6, A2): one request at
a time, as the hardware would take them."""

from __future__ import annotations

import numpy as np


def hashed_reference(stream: np.ndarray, queue: np.ndarray, p: int, s: int) -> np.ndarray:
    out: list[int] = []
    queues: list[list[int]] = [[] for _ in range(p)]

    def flush():
        while any(queues):
            fullest = max(range(p), key=lambda i: (len(queues[i]), -i))
            out.extend(queues[fullest])
            queues[fullest].clear()

    for t, q in enumerate(queue):
        if t and stream[t] != stream[t - 1]:
            flush()
        while len(queues[q]) >= s:
            fullest = max(range(p), key=lambda i: (len(queues[i]), -i))
            out.extend(queues[fullest])
            queues[fullest].clear()
        queues[q].append(t)
    flush()
    return np.array(out)
