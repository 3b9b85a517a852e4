"""Compiled kd-tree gathers and a streaming LRU cache bank: the full-scale (512 × 512) cache
simulation of Steinhurst 2007 §3.2, §3.5.

**The gather** (:func:`walk`) is Jensen's locate on the heap-order kd-tree exactly as the renderer
runs it (:meth:`photonmap.surface.kdtree.KDTree._search`): the same float32 arithmetic without
fused multiply-adds, the same k-best bound ``min(max_radius², d²_k)``, the same normal test
(:func:`photonmap.core.knn.accept`), the same push and pop rules — so it visits the same heap slots
in the same order (tested against the Dr.Jit traversal). It is compiled with Numba, one gather at a
time, which is what lets the simulator run without storing the stream.

**Streaming** (:func:`simulate`). Gathers are issued in a given order; every node a gather visits is
a read of line ``(slot − 1) div ⌊line / 20⌋`` (:mod:`.stream`'s address model), fed at once to the
cache banks of :mod:`.cache` (every capacity, every line size, the set-associative cache) — no trace
is stored, so the full image's 2–8 G reads need no memory. The node visits (the uncached naive
figure, 20 B per visit, §3.5) are counted on the way.

**Walk once, replay per order** (:func:`read_lines`). The walk costs most (a random 16-byte read
per node, 40–150 ns on this machine against 15–30 ns for a cache-bank read), and every order
permutes the same gathers; so when they fit in memory the reads are walked once, kept per gather
(line ids of 2 bytes, runs within one line merged: hits in every cache that change nothing) and
replayed order after order (:func:`photonmap.analysis.cache.simulate_reads`).
"""

from __future__ import annotations

import numba
import numpy as np

from .cache import bank, feed_bank

INDEX_MASK = np.uint32((1 << 30) - 1)
STACK_SIZE = 32  # as the renderer's traversal stack (surface/kdtree.py)


@numba.njit(cache=True, nogil=True)
def _offer(hd, hi, found, k, d, i):
    """Offer photon ``(d², index)`` to the k-best max-heap ``hd``/``hi`` holding ``found``."""
    if found < k:
        c = found
        while c > 0:
            p = (c - 1) // 2
            if hd[p] > d or (hd[p] == d and hi[p] > i):
                break
            hd[c] = hd[p]
            hi[c] = hi[p]
            c = p
        hd[c] = d
        hi[c] = i
        return found + 1
    if d < hd[0] or (d == hd[0] and i < hi[0]):
        c = 0
        while True:
            left = 2 * c + 1
            if left >= k:
                break
            big = left
            right = left + 1
            if right < k and (
                hd[right] > hd[left] or (hd[right] == hd[left] and hi[right] > hi[left])
            ):
                big = right
            if hd[big] < d or (hd[big] == d and hi[big] < i):
                break
            hd[c] = hd[big]
            hi[c] = hi[big]
            c = big
        hd[c] = d
        hi[c] = i
    return found


@numba.njit(cache=True, nogil=True)
def walk(q, qn, tree, gather, scratch):
    """Heap slots (1-based) visited by the k-NN gather at ``q`` (float32 (3,)) with normal ``qn``,
    written to ``out`` in visiting order; returns their number. ``tree = (pos, flag, pnrm,
    pdir)``: ``pos`` (N, 4) float32 and ``flag`` (N, 4) uint32 are two views of the tree's
    16-byte records in heap order (x, y, z; photon index | axis << 30 in column 3);
    ``pnrm``/``pdir`` (N, 3) the photons' normals and directions in heap order (0 rows: no such
    test). ``gather = (k, radius², cos_normal)``; ``scratch = (hd, hi, sd, sn, out)``
    (:func:`_scratch`: k and :data:`STACK_SIZE` entries, and ``out``)."""
    pos, flag, pnrm, pdir = tree
    k, radius2, cos_normal = gather
    hd, hi, sd, sn, out = scratch
    n = pos.shape[0]
    qx, qy, qz = q[0], q[1], q[2]
    if not (np.isfinite(qx) and np.isfinite(qy) and np.isfinite(qz)):
        return 0
    nx, ny, nz = qn[0], qn[1], qn[2]
    test_dir = pdir.shape[0] > 0
    test_nrm = pnrm.shape[0] > 0
    found = 0
    depth = 0
    node = 1
    visited = 0
    steps = 0
    cap = 2 * n + 2
    while True:
        bound = radius2
        if found >= k and hd[0] < bound:
            bound = hd[0]
        if node != 0:
            out[visited] = node
            visited += 1
            i = node - 1
            px, py, pz = pos[i, 0], pos[i, 1], pos[i, 2]
            dx, dy, dz = px - qx, py - qy, pz - qz
            d2 = dx * dx + dy * dy + dz * dz
            ok = d2 <= radius2
            if ok and test_dir:
                ok = pdir[i, 0] * nx + pdir[i, 1] * ny + pdir[i, 2] * nz < 0
            if ok and test_nrm:
                ok = pnrm[i, 0] * nx + pnrm[i, 1] * ny + pnrm[i, 2] * nz >= cos_normal
            f = flag[i, 3]
            if ok:
                found = _offer(hd, hi, found, k, d2, f & INDEX_MASK)
            axis = f >> 30
            if axis == 0:
                delta = qx - px
            elif axis == 1:
                delta = qy - py
            else:
                delta = qz - pz
            near = 2 * node + (0 if delta < 0 else 1)
            far = 2 * node + (1 if delta < 0 else 0)
            plane2 = delta * delta
            if far <= n and plane2 <= bound:
                top = min(depth, STACK_SIZE - 1)
                sd[top] = plane2
                sn[top] = far
                depth += 1
            node = near if near <= n else 0
        elif depth > 0:
            depth -= 1
            node = sn[depth] if sd[depth] <= bound else 0
        else:
            break
        steps += 1
        if steps >= cap:
            break
    return visited


@numba.njit(cache=True, nogil=True)
def _scratch(k, n):
    return (
        np.empty(k, np.float32),
        np.empty(k, np.uint32),
        np.empty(STACK_SIZE, np.float32),
        np.empty(STACK_SIZE, np.int64),
        np.empty(n + 1, np.int64),
    )


@numba.njit(cache=True, nogil=True, parallel=True)
def visit_counts(qpos, qnrm, tree, gather):
    """Nodes visited by each gather (Q,) (:func:`walk`'s ``tree`` and ``gather``)."""
    m = qpos.shape[0]
    count = np.zeros(m, np.int64)
    chunk = 4096
    for c in numba.prange((m + chunk - 1) // chunk):
        scratch = _scratch(gather[0], tree[0].shape[0])
        for g in range(c * chunk, min(m, (c + 1) * chunk)):
            count[g] = walk(qpos[g], qnrm[g], tree, gather, scratch)
    return count


@numba.njit(cache=True, nogil=True, parallel=True)
def visit_slots(qpos, qnrm, tree, gather, offset, total):
    """Every gather's visited heap slots, concatenated (gather ``g`` at ``offset[g]``)."""
    m = qpos.shape[0]
    slots = np.empty(total, np.int64)
    chunk = 4096
    for c in numba.prange((m + chunk - 1) // chunk):
        scratch = _scratch(gather[0], tree[0].shape[0])
        out = scratch[4]
        for g in range(c * chunk, min(m, (c + 1) * chunk)):
            v = walk(qpos[g], qnrm[g], tree, gather, scratch)
            slots[offset[g] : offset[g] + v] = out[:v]
    return slots


@numba.njit(cache=True, nogil=True)
def simulate(order, qpos, qnrm, tree, gather, caches):
    """Issue the gathers ``order`` (indices into ``qpos``/``qnrm``) and feed every node read to
    one cache bank per line size; ``caches = (per_line, segcap, sets, ways)``: ``per_line``
    (L,) photons per line, ``segcap`` (L, K) the segment sizes, in lines, of the fully
    associative capacities, ``sets`` (L,) sets of the ``ways``-way cache, 0 for none. Returns
    ``(misses (L, K), set-associative misses (L,), compulsory (L,), visits)``."""
    per_line, segcap, sets, ways = caches
    n = tree[0].shape[0]
    L = per_line.shape[0]
    banks = [
        bank((n + per_line[b] - 1) // per_line[b] + 1, segcap[b], sets[b], ways) for b in range(L)
    ]
    visits = 0
    scratch = _scratch(gather[0], n)
    out = scratch[4]
    for g in order:
        v = walk(qpos[g], qnrm[g], tree, gather, scratch)
        visits += v
        for b in range(L):
            feed_bank(out, (0, v), 1, per_line[b], banks[b])
    misses = np.empty((L, segcap.shape[1]), np.int64)
    state = np.empty((L, 3), np.int64)
    for b in range(L):
        misses[b] = banks[b][7]
        state[b] = banks[b][8]
    return misses, state[:, 2], state[:, 1], visits


@numba.njit(cache=True, nogil=True)
def read_lines(qpos, qnrm, tree, gather, per_line, kind, size):
    """Every gather's line reads with runs within one line merged (hits in every cache that
    change nothing), concatenated in gather order into a buffer of ``kind``'s dtype, first
    ``size`` long (grown by half when full): ``(count (Q,), buffer, used, visits)``."""
    m = qpos.shape[0]
    count = np.zeros(m, np.int64)
    lines = np.empty(max(size, 1024), kind.dtype)
    used = 0
    visits = 0
    scratch = _scratch(gather[0], tree[0].shape[0])
    out = scratch[4]
    for g in range(m):
        v = walk(qpos[g], qnrm[g], tree, gather, scratch)
        visits += v
        if used + v > lines.shape[0]:
            grown = np.empty(max(lines.shape[0] * 3 // 2, used + v), kind.dtype)
            grown[:used] = lines[:used]
            lines = grown
        start = used
        last = -1
        for t in range(v):
            x = (out[t] - 1) // per_line
            if x != last:
                lines[used] = x
                used += 1
                last = x
        count[g] = used - start
    return count, lines, used, visits
