"""The techniques of vertex connection and merging and their multiple-importance weights
(Georgiev, Křivánek, Davidovič & Slusallek 2012, "Light transport simulation with vertex connection
and merging", §4–5; Georgiev 2012, "Implementing vertex connection and merging", the technical
report whose equations are cited as TR (n); SmallVCM's ``vertexcm.hxx``).

A path of ``k`` segments can be made by several techniques: the camera subpath hits the light
(``s = 0``), it is connected to a point sampled on a light (next-event estimation, ``s = 1``),
to a vertex of a light subpath (``s ≥ 2``), a light subpath vertex is connected to the camera
(light tracing, ``t = 1``), or the two subpaths' vertices within the radius ``r`` are merged
(vertex merging: photon mapping). Their balance-heuristic weights are computed from three
quantities carried along each subpath (TR §5.3), updated at each vertex from the BSDF's forward
and reverse densities:

- ``dVCM``: the techniques whose subpath ends at the previous vertex (TR (31), (34));
- ``dVC``: the sum over the connections further back (TR (32), (35));
- ``dVM``: the same for merges (TR (33), (36)).

Merging competes with connection through ``η_VCM = π r² N_L`` (TR (21)): ``N_L`` light subpaths
are merged with where one is connected to. An iteration traces ``spp`` camera subpaths per pixel
and as many light subpaths, ``N_L = spp · P`` for ``P`` pixels (SmallVCM's ``spp = 1``): light
tracing's density relative to a camera subpath's, ``spp · P · W_e / N_L``, is then the
sensor importance ``W_e`` whatever ``spp``, and the recursions are unchanged. The weight of one technique is
``1 / (w_light + 1 + w_camera)`` (TR (37)) with the partial weights of TR (38)–(47).

**Modes** (SmallVCM's algorithms), which must all converge to the same image:

=========  ===========================================================================
``vcm``    every technique, weighted (TR (37))
``bpt``    bidirectional path tracing: next-event estimation, connections, light tracing
``ppm``    progressive photon mapping: merging at the first smooth camera vertex, unweighted
           (the emission met along purely specular camera paths adds to it)
``pt``     path tracing with next-event estimation, the two weighted by the balance heuristic
``lt``     light tracing: light subpath vertices connected to the camera (the emission seen
           directly comes from the camera rays, as every mode has it)
=========  ===========================================================================

Russian roulette is left out of the densities (as pbrt-v4's BDPT does): each technique's weight
is computed from the same densities, so the weights of all techniques of a path still sum to one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

MODES = ("vcm", "bpt", "ppm", "pt", "lt")


@dataclass(frozen=True)
class Techniques:
    """Which techniques a mode uses, and the iteration's merging constants."""

    mode: str
    light_paths: int  # N_L: spp per pixel, as many as camera subpaths
    radius: float  # the iteration's merging radius r_i (scene units)
    spp: int = 1  # camera subpaths per pixel (the light subpaths are N_L = spp × pixels)

    @property
    def nee(self) -> bool:
        """Camera vertices connect to points sampled on the lights."""
        return self.mode in ("vcm", "bpt", "pt")

    @property
    def connect(self) -> bool:
        """Camera vertices connect to the vertices of their light subpath; the subpaths carry
        ``dVC`` (no other mode needs it)."""
        return self.mode in ("vcm", "bpt")

    @property
    def light_tracing(self) -> bool:
        """Light subpath vertices connect to the camera."""
        return self.mode in ("vcm", "bpt", "lt")

    @property
    def merge(self) -> bool:
        return self.mode in ("vcm", "ppm")

    @property
    def light_pass(self) -> bool:
        """Light subpaths are traced."""
        return self.mode != "pt"

    @property
    def eta(self) -> float:
        """``η_VCM = π r² N_L`` (TR (21))."""
        return math.pi * self.radius**2 * self.light_paths

    @property
    def vm_factor(self) -> float:
        """Weight of merging relative to connecting at one vertex, ``η_VCM`` (0 without
        weighted merging)."""
        return self.eta if self.mode == "vcm" else 0.0

    @property
    def vc_factor(self) -> float:
        """Weight of connecting relative to merging, ``1 / η_VCM`` (0 without connections)."""
        return 1.0 / self.eta if self.mode == "vcm" and self.eta > 0 else 0.0

    @property
    def merge_normalization(self) -> float:
        """``1 / (π r² N_L)``: a merge's kernel over the light subpaths (TR (21))."""
        return 1.0 / self.eta


# ----------------------------------------------------------------------------------------------
# The recursive quantities and the weights (TR (31)–(47)). Plain arithmetic on the densities,
# so they take Dr.Jit arrays and NumPy arrays alike (``tests/vcm/test_mis.py`` checks them
# against the balance heuristic of explicit path densities). ``vcm, vc, vm`` are a subpath's
# dVCM, dVC and dVM.


def light_start(p_e, cos_light, vc_factor):
    """A light subpath's quantities at its light vertex (TR (31)–(33)), without ``dVCM``, which
    the first hit sets from next-event estimation's density (:func:`first_light_hit`):
    ``dVC = cos θ_L / p_e``, ``dVM = dVC / η``. ``p_e``: the emission density per area and solid
    angle (0 ``dVC`` for delta lights is the caller's)."""
    vc = cos_light / p_e
    return vc, vc * vc_factor


def first_light_hit(p_direct_area, p_e, dist2, cos_in):
    """``dVCM`` at a light subpath's first hit: ``p_direct / p_e`` (TR (31), next-event
    estimation's density of the light point per area over the emission density) completed
    there (× d², ÷ |cos θ_i|)."""
    return p_direct_area * dist2 / (p_e * cos_in)


def after_hit(vcm, vc, vm, dist2, cos_in):
    """The quantities completed at a hit (TR (31)–(36)): ``dVCM × d²``, all ``÷ |cos θ_i|``."""
    return vcm * dist2 / cos_in, vc / cos_in, vm / cos_in


def after_bounce(vcm, vc, vm, cos_out, pdf, p_rev, vm_factor, vc_factor):
    """The quantities after a BSDF sample of density ``pdf`` (its reverse ``p_rev``) leaving at
    ``cos θ_o`` (TR (34)–(36))."""
    ratio = cos_out / pdf
    return 1.0 / pdf, ratio * (vc * p_rev + vcm + vm_factor), ratio * (vm * p_rev + vcm * vc_factor
                                                                       + 1.0)


def after_delta(vcm, vc, vm, cos_out):
    """The quantities after a delta (specular) bounce: ``dVCM = 0`` (nothing connects to that
    vertex), the others × ``cos θ_o`` (TR (34)–(36) with ``p_rev = pdf``)."""
    return vcm * 0.0, vc * cos_out, vm * cos_out


def emission_weight(vcm, vc, p_direct_area, p_e):
    """A camera subpath that meets an emitter (TR (42)–(43)): ``1 / (1 + p_direct dVCM + p_e
    dVC)``, ``p_direct`` per area."""
    return 1.0 / (1.0 + p_direct_area * vcm + p_e * vc)


def next_event_weight(camera, light, vm_factor):
    """Next-event estimation (TR (44)–(45)): ``w_light = p_bsdf / p_direct`` (both per solid
    angle at the camera vertex), ``w_camera = p_e cos θ / (p_direct cos θ_L) (η + dVCM + dVC
    p_rev)``. ``camera``: the camera end ``(dVCM, dVC, p_bsdf, p_rev, cos θ)`` as in
    :func:`connection_weight`; ``light``: the light sample ``(p_direct, p_e, cos θ_L)``."""
    vcm, vc, p_forward, p_rev, cos_here = camera
    p_direct, p_e, cos_light = light
    w_light = p_forward / p_direct
    w_camera = p_e * cos_here / (p_direct * cos_light) * (vm_factor + vcm + vc * p_rev)
    return 1.0 / (w_light + 1.0 + w_camera)


def connection_weight(light, camera, dist2, vm_factor):
    """A camera vertex connected to a light vertex (TR (40)–(41)) at squared distance
    ``dist2``. Each end is ``(dVCM, dVC, p, p_rev, cos θ)``: its subpath's quantities, its
    BSDF's density of the direction to the other end and of the reverse, its cosine."""
    vcm_l, vc_l, p_light, p_light_rev, cos_light = light
    vcm_c, vc_c, p_camera, p_camera_rev, cos_camera = camera
    w_light = p_camera * cos_light / dist2 * (vm_factor + vcm_l + vc_l * p_light_rev)
    w_camera = p_light * cos_camera / dist2 * (vm_factor + vcm_c + vc_c * p_camera_rev)
    return 1.0 / (w_light + 1.0 + w_camera)


def light_tracing_weight(vcm, vc, p_camera, p_rev, vm_factor):
    """A light vertex connected to the camera (TR (46)–(47)): ``1 / (1 + p_cam (η + dVCM + dVC
    p_rev))``, ``p_cam`` the camera's density of the vertex per area over ``N_L``."""
    return 1.0 / (1.0 + p_camera * (vm_factor + vcm + vc * p_rev))


def merge_weight(light, camera, p, p_rev, vc_factor):
    """A camera vertex merged with a light vertex (TR (38)–(39)); ``light`` and ``camera`` are
    ``(dVCM, dVM)``, ``p`` the camera BSDF's density of the light's incoming direction,
    ``p_rev`` the reverse."""
    w_light = light[0] * vc_factor + light[1] * p
    w_camera = camera[0] * vc_factor + camera[1] * p_rev
    return 1.0 / (w_light + 1.0 + w_camera)
