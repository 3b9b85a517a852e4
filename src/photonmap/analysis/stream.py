"""The photon-map address stream of a render's final gathers (Steinhurst 2007 §3.2, §3.5, §4.2;
spec seed-001 §2.3, §2.6, ambiguities A6, A17, A20).

A render of the surface method with exact k-NN final gathers on the heap-order kd-tree
(``lookup="knn"``, ``structure="kdtree"``) keeps its request batches
(:class:`~photonmap.surface.gather_batch.GatherBatch`). Each request's gather is then run once more
with the traversal recording the heap slots it visits, in visiting order
(:meth:`~photonmap.surface.kdtree.KDTree.visits`): the exact record reads of that gather. A gather
order is a permutation of the requests, so the stream of an order is the concatenation of the
requests' visit lists in that order.

**Address model** (spec §2.3): Jensen's 20-byte photon records in heap order, node ``i`` (1-based)
in line ``(i − 1) div ⌊line_bytes / 20⌋`` (no record straddles two lines; the rest of a line is the
"bookkeeping" slack, 6 photons per 128-byte line). The **uncached naive** bandwidth of the
dissertation ("20 bytes reads of single photons scattered across memory", §3.5) is 20 bytes per
visited node. The stream holds the indirect (final-gather) gathers only, the ones the
dissertation's reorderings act on (A20: caustic gathers, one per pixel at ``x``, read their own map
in a disjoint address range and are the same in every order).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.errors import ParameterError
from ..surface.gather_batch import GatherBatch, OrderParams, gather_order
from ..surface.pipeline import SurfacePipeline

RECORD_BYTES = 20  # Jensen's compact photon (spec §2.3)
TRACE_CHUNK = 1 << 17  # gathers traced per kernel launch
MAX_VISITS = 200_000_000  # node visits a trace may hold (4 bytes each, and 8 per stream entry)


@dataclass
class GatherTrace:
    """Final-gather requests of one render and the kd-tree nodes each visits: request ``r``'s
    heap slots are ``slots[offset[r] : offset[r] + count[r]]``."""

    batch: GatherBatch
    count: np.ndarray
    offset: np.ndarray
    slots: np.ndarray
    photons: int
    # the gathers' parameters and the global map's photons (N, 3) float32 each, original order:
    # position, normal, direction — what other structures need to rerun the same gathers
    k: int = 0
    radius: float = 0.0
    photon_data: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    @property
    def visits(self) -> int:
        return int(self.count.sum())

    def uncached_bytes(self) -> int:
        """The dissertation's naive figure: one 20-byte read per visited node (§3.5)."""
        return self.visits * RECORD_BYTES

    def footprint_lines(self, line_bytes: int) -> int:
        """Lines of the whole global map."""
        return -(-self.photons // photons_per_line(line_bytes))

    def lines(self, order: str, line_bytes: int, params: OrderParams | None = None) -> np.ndarray:
        """The stream of cache-line ids the gathers read when issued in ``order``."""
        perm = gather_order(self.batch, order, params)
        count = self.count[perm]
        total = int(count.sum())
        start = np.repeat(self.offset[perm] - (np.cumsum(count) - count), count)
        slots = self.slots[start + np.arange(total)]
        return (slots.astype(np.int64) - 1) // photons_per_line(line_bytes)


def photons_per_line(line_bytes: int) -> int:
    """``⌊line_bytes / 20⌋`` photon records per cache line (spec §2.3: 64 → 3, 128 → 6)."""
    per_line = int(line_bytes) // RECORD_BYTES
    if per_line < 1:
        raise ParameterError(
            f"a cache line must hold at least one {RECORD_BYTES}-byte photon, got {line_bytes} B"
        )
    return per_line


def trace_final_gathers(scene, **params) -> GatherTrace:
    """Render ``scene`` with the surface method (``params``: its parameters and scene
    parameters) using exact k-NN final gathers on the kd-tree, and trace every gather."""
    pipe = SurfacePipeline(
        scene, **{**params, "lookup": "knn", "structure": "kdtree", "gather_order": "naive"}
    )
    pipe.kept_requests = []
    pipe.render()
    batches = pipe.kept_requests
    batch = GatherBatch(
        *(np.concatenate([getattr(b, f) for b in batches]) for f in _ARRAYS),
        width=batches[0].width,
        height=batches[0].height,
        bounds=batches[0].bounds,
    )
    global_map = pipe.photon_maps()[0]
    _, radius = pipe.radii()
    counts, slots = [], []
    for first in range(0, len(batch), TRACE_CHUNK):
        part = slice(first, first + TRACE_CHUNK)
        c, s = global_map.structure.visits(
            mi.Point3f(*batch.position[part].T),
            pipe.params.k,
            radius,
            mi.Vector3f(*batch.normal[part].T),
            global_map.photons.normal,
            global_map.photons.direction,
        )
        counts.append(c)
        slots.append(s)
        if sum(len(x) for x in slots) > MAX_VISITS:
            raise ParameterError(
                f"the final gathers visit more than {MAX_VISITS:,} kd-tree nodes; trace a "
                "smaller image or crop, fewer fg_rays, or a smaller max_radius"
            )
    dr.sync_thread()
    count = np.concatenate(counts)
    photon_data = tuple(
        np.asarray(v.numpy(), np.float32).reshape(3, -1).T.copy()
        for v in (
            global_map.photons.position,
            global_map.photons.normal,
            global_map.photons.direction,
        )
    )
    return GatherTrace(
        batch,
        count,
        np.cumsum(count) - count,
        np.concatenate(slots),
        global_map.size,
        pipe.params.k,
        radius,
        photon_data,
    )


_ARRAYS = ("position", "normal", "direction", "pixel", "ray", "specular")


def cropped_scene(name: str, size: int, offset: tuple[int, int], crop: tuple[int, int], **params):
    """The built-in scene ``name`` rendered at ``size`` × ``size`` but only in the film crop at
    ``offset`` (x, y) of ``crop`` (w, h) pixels — a window of the dissertation's 512 × 512 image
    with its pixel footprint, so that each tile's gathers are as coherent as at full size (spec
    A17: down-scaled runs keep the photon map and the cache)."""
    from ..scenes import SCENES

    if name not in SCENES:
        raise ParameterError(f"no built-in scene named {name!r}")
    scene = SCENES[name].build(width=size, height=size, **params)
    film = scene["sensor"]["film"]
    if not (
        0 <= offset[0]
        and offset[0] + crop[0] <= size
        and 0 <= offset[1]
        and offset[1] + crop[1] <= size
    ):
        raise ParameterError(f"the crop {crop} at {offset} leaves the {size}² image")
    film.update(
        crop_offset_x=offset[0], crop_offset_y=offset[1], crop_width=crop[0], crop_height=crop[1]
    )
    return scene
