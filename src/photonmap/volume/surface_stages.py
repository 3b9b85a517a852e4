"""The opaque surfaces in the volume pipeline's stages (``pipeline.py``): what the photon and
viewing stages' cache keys hold of them, the viewing pass's :class:`~.shading.SurfaceShading`,
and the warnings about what the settings leave out of a scene with surfaces (the photons on the
surfaces are a photon-stage output, their shading a viewing-stage output, as Sun et al. 2008 §6
keeps the photons across camera moves)."""

from __future__ import annotations

import warnings

from ..core.errors import PhotonmapWarning
from ..core.scene_info import warn_unmodelled
from ..core.stages import cache_key
from .params import VolumeParams
from .scene import SURFACE_HINT, VolumeScene
from .shading import SurfaceShading

AUTOMATIC_RADIUS = 8.0  # voxels: the surface gathers' radius when ``radius`` is 0


def surface_key(s: VolumeScene):
    """What the photon stages see of the opaque surfaces (their shapes' parameters)."""
    surf = s.surfaces
    return None if surf is None else (id(surf.scene), surf.fingerprint)


def emission(s: VolumeScene, bounce: bool) -> dict:
    """S5's keywords with opaque surfaces (``emit.emit_lights``): photons start at the lights
    (the marcher checks their way to the grid), and, where they bounce (``bounce``: multiple
    scattering) off surfaces other than the lamps' own shapes, light the whole scene
    (``emit.emit_everywhere``)."""
    surf = s.surfaces
    reflecting = surf is not None and len(surf.names) > surf.lamps
    everywhere = surf.bounds() if reflecting and bounce else None
    return {"keep_origin": surf is not None, "scene_bounds": everywhere}


def surface_shading(s: VolumeScene, p: VolumeParams, photons, view_grids) -> SurfaceShading | None:
    """S9's inputs at the surfaces: the surfaces, the lights, the photons recorded on them (the
    photon stage's output), the gather's k and radius, and the grid's κ; None without surfaces."""
    if s.surfaces is None:
        return None
    radius = p.radius if p.radius > 0 else AUTOMATIC_RADIUS * s.box.h
    return SurfaceShading(
        s.surfaces,
        s.lights,
        photons,
        p.k,
        radius,
        p.light_samples,
        view_grids.kappa,
        view_grids.dims,
    )


def shading_key(s: VolumeScene, p: VolumeParams, shading: SurfaceShading | None):
    """The viewing stage's key of the surfaces' shading (None without surfaces)."""
    if shading is None:
        return None
    lights = cache_key(s.lights)
    return surface_key(s), id(shading.photons), lights, p.k, shading.max_radius, p.light_samples


def warn_settings(s: VolumeScene, p: VolumeParams, warned: set) -> None:
    """Say, once per pipeline (``warned``: what was said) and setting, what the settings leave
    out of a scene with opaque surfaces."""
    # light reflected by the lamps' own shapes alone is too little to mention
    if s.surfaces is None or len(s.surfaces.names) == s.surfaces.lamps:
        return
    if p.spp == 1 and "spp" not in warned:
        warned.add("spp")
        warnings.warn(
            "one camera ray through each pixel centre aliases the surfaces' edges and the small "
            "images of lights in glass, which the film's filter averages over the pixel: raise "
            "--set spp (or --spp), e.g. to 4 (64 where a small light is seen through glass)",
            PhotonmapWarning,
            stacklevel=4,
        )
    parts = []
    if p.scattering == "single":
        parts.append(
            "with scattering='single' photons neither scatter nor bounce off surfaces: the "
            "light the fog scatters onto surfaces and the light surfaces reflect (onto others "
            "and into the fog); use scattering='multiple'"
        )
    if p.emission == "adaptive":
        parts.append(
            "with emission='adaptive' photons start on a plane in front of the grid: the light "
            "that reaches surfaces outside the grid's silhouette and what they reflect into the "
            "fog; use emission='uniform'"
        )
    new = [part for part in parts if part not in warned]
    warned.update(new)
    warn_unmodelled("volume", new, SURFACE_HINT)
