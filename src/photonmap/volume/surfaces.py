"""The opaque surfaces of the user's scene in the volume method: what stops photons and camera
rays, and the photons recorded on them.

Sun et al. 2008 render a voxel grid (their Fig. 1 stands a glass object on a table whose caustic
the photons paint; Pfeuti 2009 §3.1.6 makes the table the grid's bottom voxel layer). A Mitsuba
scene also holds surfaces anywhere — a floor under the fog box, walls, blocks, the lamp itself —
and they are Mitsuba shapes here, found by Mitsuba's ray casts (``scene.ray_intersect``), not
voxels. Which shape is what, by the lobes of its BSDF:

- a ``Null`` lobe (``null``, ``thindielectric``, ``mask``): an index-matched boundary — a fog
  volume's shape — that every ray crosses unchanged (its interior medium is in the grid);
- a ``DeltaTransmission`` lobe without ``Null`` (``dielectric``): a refractive object, voxelized
  into the grid; photons and camera rays cross its surface and bend through ∇n (Sun §4.4) while
  shadow rays stop at it — the light that passes it is refracted, and arrives as photons;
- anything else, and every emitter shape: **opaque**. Photons and camera rays stop there.

Marching keeps one cast per straight stretch: :meth:`Surfaces.distance` casts from a point in
voxel coordinates past the crossing shapes and returns the distance to the first opaque surface;
the marchers cast again only after their direction has turned by more than
:data:`RECAST_TURN` (inside and around refractive objects, where ∇n ≠ 0).

:class:`SurfacePhotons` are the photons that reach an opaque surface after at least one event —
a refraction through an object, a scattering in the fog, a bounce off a surface — (position,
direction, power, surface normal): Jensen's photon map on the surfaces, whose radiance estimate
``Σ f Φ / (π r²)`` (Jensen 1996 §3; Sun Fig. 1's caustic on the table) the viewing pass adds to
the direct light it computes itself (light arriving straight from the emitters is never stored,
so it is not counted twice).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.arrays import concat
from ..core.bsdf import pass_through
from ..core.grid import GridBox
from ..core.hashgrid import HashGrid

MAX_CROSSINGS = 32  # crossing shapes skipped by one cast (iteration cap)
RECAST_TURN = 1e-3  # |d − d_cast|: a direction change past which a marcher casts again
NULL = int(mi.BSDFFlags.Null)
OBJECT = int(mi.BSDFFlags.DeltaTransmission)


def kind(shape) -> str:
    """``"crossing"`` (a ``Null`` lobe: fog boundaries), ``"object"`` (a smooth dielectric) or
    ``"opaque"`` for a Mitsuba shape (module docstring)."""
    if shape.is_emitter():
        return "opaque"
    flags = int(shape.bsdf().flags()) if shape.bsdf() is not None else 0
    if flags & NULL:
        return "crossing"
    if flags & OBJECT:
        return "object"
    return "opaque"


def shape_name(shape) -> str:
    """A shape's id, else its type and BSDF (Mitsuba files often leave ids out)."""
    bsdf = shape.bsdf().class_name() if shape.bsdf() is not None else "no"
    return f"'{shape.id()}'" if shape.id() else f"a {shape.class_name()} with a {bsdf} BSDF"


def unmodelled(shapes) -> list[str]:
    """What the volume method does not render of these shapes, one line per shape: partial
    transparency (``mask``, a ``thindielectric`` that bounds no fog), which it renders as fully
    transparent. (Mirror lobes are followed by the camera rays, ``view.py``, and by the photons.)"""
    lines = []
    for shape in shapes:
        bsdf = shape.bsdf()
        flags = int(bsdf.flags()) if bsdf is not None else 0
        crossing = flags & NULL and flags & ~NULL & int(mi.BSDFFlags.All)
        if crossing and shape.interior_medium() is None:  # not a fog volume's boundary
            lines.append(f"{shape_name(shape)}, partly transparent: rendered as fully transparent")
    return lines


def _crosses(scene, si, ray, active, objects: bool) -> mi.Bool:
    """Lanes whose hit is a crossing shape (or, with ``objects``, a refractive object's surface)
    that emits nothing: the ray goes on."""
    hit = active & si.is_valid()
    lobes = NULL | (OBJECT if objects else 0)
    crossing = (mi.UInt32(si.bsdf(ray).flags()) & lobes) != 0
    return hit & crossing & (si.emitter(scene) == None)  # noqa: E711


def first_hit(scene, ray: mi.Ray3f, active, objects: bool = True) -> mi.SurfaceInteraction3f:
    """The first hit along ``ray`` that is not a crossing shape (nor, with ``objects``, a
    refractive object's surface), or an invalid interaction; ``si.t`` from ``ray.o``."""
    active = mi.Bool(active)
    si = scene.ray_intersect(ray, active)

    def crosses(si, ray, going):
        return _crosses(scene, si, ray, going, objects)

    return pass_through(scene, ray, si, active, crosses, MAX_CROSSINGS)


class Surfaces:
    """The opaque surfaces of ``scene`` (a Mitsuba scene) seen from the grid ``box``: casts in
    voxel coordinates (module docstring). ``names``: the opaque shapes, for messages;
    ``fingerprint``: a digest of their parameters. (A plain class: the marchers' symbolic loops
    read it, and Dr.Jit would traverse a dataclass as loop state.)"""

    def __init__(
        self, scene: mi.Scene, box: GridBox, names: list, fingerprint: str = "", lamps: int = 0
    ):
        self.scene, self.box, self.names, self.fingerprint = scene, box, names, fingerprint
        self.lamps = lamps  # how many of them are emitters' shapes
        self._lo = mi.Point3f(*[dr.opaque(mi.Float, float(c)) for c in self.box.lo])
        self._h = dr.opaque(mi.Float, float(self.box.h))

    @staticmethod
    def of(scene: mi.Scene, box: GridBox) -> Surfaces | None:
        """The opaque surfaces of ``scene``; None when it has none."""
        opaque = [s for s in scene.shapes() if kind(s) == "opaque"]
        if not opaque:
            return None
        lamps = sum(s.is_emitter() for s in opaque)
        return Surfaces(scene, box, [shape_name(s) for s in opaque], digest(*opaque), lamps)

    def world(self, x: mi.Point3f) -> mi.Point3f:
        """Voxel coordinates → world."""
        return mi.Point3f(self._lo + x * self._h)

    def voxel(self, p: mi.Point3f) -> mi.Point3f:
        """World → voxel coordinates."""
        return mi.Point3f((p - self._lo) / self._h)

    def in_voxels(self, length) -> mi.Float:
        """A world length in voxels."""
        return mi.Float(length) / self._h

    def bounds(self) -> tuple[np.ndarray, float]:
        """The centre and radius of the scene's bounding sphere, voxel coordinates."""
        bbox = self.scene.bbox()
        lo, hi = (np.asarray(v, dtype=np.float64).reshape(3) for v in (bbox.min, bbox.max))
        return self.box.to_voxel(0.5 * (lo + hi)), 0.5 * float(np.linalg.norm(hi - lo)) / self.box.h

    def hit(self, x: mi.Point3f, d: mi.Vector3f, active) -> mi.SurfaceInteraction3f:
        """The first opaque surface from voxel point ``x`` along ``d`` (world interaction)."""
        return first_hit(self.scene, mi.Ray3f(self.world(x), mi.Vector3f(d)), active)

    def distance(self, x: mi.Point3f, d: mi.Vector3f, active) -> mi.Float:
        """Distance in voxels from ``x`` along unit ``d`` to the first opaque surface (∞: none)."""
        si = self.hit(x, d, active)
        return dr.select(active & si.is_valid(), si.t / self._h, dr.inf)

    def occluded(self, ray: mi.Ray3f, active) -> mi.Bool:
        """Whether something other than a crossing shape lies on the finite world ``ray``:
        shadow rays stop at refractive objects too (their light arrives as photons)."""
        return active & first_hit(self.scene, ray, active, objects=False).is_valid()

    def towards_light(self, ray: mi.Ray3f, active) -> mi.SurfaceInteraction3f:
        """The first hit of a BSDF-sampled world ray that is not a crossing shape (a refractive
        object hides the emitters behind it, as for :meth:`occluded`)."""
        return first_hit(self.scene, ray, active, objects=False)


def digest(*objects) -> str:
    """A digest of the parameters of Mitsuba objects (``mi.traverse``): an emitter or a shape
    edited through ``mi.traverse`` and re-read by ``reload`` changes the cache keys it is in."""
    h = hashlib.sha1()
    for obj in objects:
        params = mi.traverse(obj)
        for key in sorted(params.keys()):
            try:
                value = params[key]
                value = np.asarray(getattr(value, "matrix", value), dtype=np.float64)
            except (TypeError, ValueError):
                continue
            h.update(key.encode())
            h.update(value.tobytes())
    return h.hexdigest()


# ------------------------------------------------------------------------------------------------
# Photons on the surfaces


@dataclass
class SurfacePhotons:
    """Photons recorded where they reached an opaque surface after an event (world units):
    position, travel direction, power (W) and the surface's shading normal; ``map`` is the hash
    grid over the positions (:class:`~photonmap.core.hashgrid.HashGrid`)."""

    position: mi.Point3f
    direction: mi.Vector3f
    power: mi.Color3f
    normal: mi.Vector3f
    map: HashGrid | None = None

    @property
    def count(self) -> int:
        return dr.width(self.power)

    @staticmethod
    def concat(batches: list) -> SurfacePhotons:
        """One list from the batches of the photon orders, with its hash grid."""
        batches = [b for b in batches if b.count > 0]
        if not batches:
            zero = dr.zeros(mi.Point3f, 0)
            return SurfacePhotons(zero, mi.Vector3f(zero), mi.Color3f(zero), mi.Vector3f(zero))

        def cat(cls, name):
            return cls(concat([getattr(b, name) for b in batches]))

        out = SurfacePhotons(
            cat(mi.Point3f, "position"),
            cat(mi.Vector3f, "direction"),
            cat(mi.Color3f, "power"),
            cat(mi.Vector3f, "normal"),
        )
        dr.eval(out.position, out.direction, out.power, out.normal)
        out.map = HashGrid(out.position)
        return out


def record(position, direction, power, normal, keep) -> SurfacePhotons:
    """The photons of the lanes ``keep``, compacted."""
    index = dr.compress(mi.Bool(keep))
    out = SurfacePhotons(
        dr.gather(mi.Point3f, position, index),
        dr.gather(mi.Vector3f, direction, index),
        dr.gather(mi.Color3f, power, index),
        dr.gather(mi.Vector3f, normal, index),
    )
    dr.eval(out.position, out.direction, out.power, out.normal)
    return out
