"""Small scenes for the differentiable photon-mapping tests, each with the parameters whose
gradients are checked: a light over a diffuse plane, a glass slab over a plane, a fog box over a
plane. The camera sees the receiver directly (not through glass), and the loss weights only
receiver pixels, so that no visibility change (the light's image in the glass moving) enters the
finite differences: those discontinuities are not differentiated, by design."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from photonmap.core.arrays import to_jit
from photonmap.sppm.differentiable import DifferentiablePhotonMapper

T = mi.ScalarTransform4f
SIZE = 24
PHOTONS = 40_000
RADIUS = 0.2


def quad(z: float, half: float, bsdf: dict, flip: bool = False) -> dict:
    """A two-triangle mesh square at height ``z`` (normal +z, or −z when ``flip``)."""
    mesh = mi.Mesh("quad", 4, 2, has_vertex_normals=True)
    params = mi.traverse(mesh)
    params["vertex_positions"] = [-half, -half, z, half, -half, z, half, half, z, -half, half, z]
    params["faces"] = [0, 2, 1, 0, 3, 2] if flip else [0, 1, 2, 0, 2, 3]
    params["vertex_normals"] = [0, 0, -1 if flip else 1] * 4
    params.update()
    mesh.set_bsdf(mi.load_dict(bsdf))
    return mesh


def diffuse(value: float) -> dict:
    return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [value] * 3}}


def base(max_depth: int, origin=(0, -3, 0.8)) -> dict:
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": max_depth},
        "sensor": {
            "type": "perspective", "fov": 40,
            "to_world": T().look_at(origin=list(origin), target=[0, 0, 0], up=[0, 0, 1]),
            "film": {"type": "hdrfilm", "width": SIZE, "height": SIZE,
                     "rfilter": {"type": "box"}},
        },  # fmt: skip
        "light": {
            "type": "rectangle",
            "to_world": T().translate([0, 0, 3]).rotate([1, 0, 0], 180).scale(0.2),
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [40.0] * 3}},
        },
        "floor": quad(0.0, 3.0, diffuse(0.5)),
    }


def plane_scene() -> mi.Scene:
    """A small area light over a diffuse plane (no occluder)."""
    return mi.load_dict(base(3, origin=(0, -3, 4)))


def slab_scene() -> mi.Scene:
    """A 12 × 12 × 0.2 slab of ``diff_dielectric`` glass (a mesh) between the light and the
    plane; the camera looks at the plane from under the slab. (The slab is wide: light that its
    side faces reflect inwards — whether a photon meets a side face before the bottom changes
    abruptly as the slab moves, a visibility event that is not differentiated — lands off the
    plane; on a 4 × 4 slab it carried half the finite difference of raising the top.)"""
    scene = base(6)
    scene["slab"] = {
        "type": "cube", "to_world": T().translate([0, 0, 1.2]).scale([6, 6, 0.1]),
        "bsdf": {"type": "diff_dielectric", "int_ior": 1.5},
    }  # fmt: skip
    return mi.load_dict(scene)


def fog_scene() -> mi.Scene:
    """A box of homogeneous fog (``null`` boundary) over the plane, the camera outside it."""
    scene = base(6, origin=(0, -4, 1.5))
    scene["fog"] = {
        "type": "cube", "to_world": T().translate([0, 0, 1.0]).scale([1.5, 1.5, 0.8]),
        "bsdf": {"type": "null"},
        "interior": {"type": "homogeneous", "sigma_t": 0.8, "albedo": {"type": "rgb",
                                                                         "value": [0.8] * 3}},
    }  # fmt: skip
    return mi.load_dict(scene)


def receiver_weight(rows_from: int) -> mi.TensorXf:
    """A smooth weight over the receiver's pixels (rows ≥ ``rows_from``), zero elsewhere."""
    y, x = np.mgrid[0:SIZE, 0:SIZE]
    w = np.exp(-((x - SIZE / 2) ** 2 + (y - 0.7 * SIZE) ** 2) / (0.1 * SIZE**2)) * (y >= rows_from)
    return to_jit(mi.TensorXf, np.repeat(w[..., None], 3, axis=2))


def weighted_sum(scene, weight, seed: int, photons: int = PHOTONS) -> mi.Float:
    """The differentiable estimate's weighted pixel sum (fixed radii: finite differences of
    the same estimator)."""
    image = DifferentiablePhotonMapper(
        scene, photons=photons, radius=RADIUS, volume_radius=RADIUS
    ).render(seed)
    return dr.sum(image * weight, axis=None)
