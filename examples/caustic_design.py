"""Caustic design with differentiable photon mapping.

A glass slab under a distant light casts a caustic on a white floor. Its exit face is a grid of
vertices that we push up or down (a heightmap); Adam moves them until the caustic shows a target
picture: here a smiley drawn with NumPy. Each step renders the caustic with
``photonmap.render(scene, params, ...)`` (photons traced from the light through the glass,
density-estimated on the floor, differentiable in the vertex positions) and backpropagates an
L2 loss. The set-up follows Mitsuba 3's caustic-design tutorial. At the end Mitsuba's own
particle tracer (``ptracer``) renders the optimised slab, as an independent check.

    .venv/bin/python examples/caustic_design.py [--quick] [--steps 300] [--out out/caustic_design]

Writes ``target.png``, ``estimate.png`` (the last photon-mapped image), ``ptracer.png`` and
``side_by_side.png`` (target | Mitsuba's render of the result) in ``--out``.
"""

import argparse
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

import photonmap  # selects the llvm_ad_rgb variant

MAX_DEPTH = 4  # light -> slab entry -> slab exit -> floor -> camera


def glass():
    """The tutorial's glass: ior 1.5, no specular reflection (all light goes through)."""
    return {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0,
            "specular_reflectance": {"type": "spectrum", "value": 0.0}}  # fmt: skip


def exit_face(n):
    """An n x n vertex grid over [-1, 1]^2 at y = 0, facing down (-y), made of glass."""
    u, v = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n), indexing="ij")
    positions = np.stack([u, np.zeros_like(u), v], -1)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    faces = np.concatenate([np.stack([a, a + n, a + 1], 1), np.stack([a + 1, a + n, a + n + 1], 1)])
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(glass())
    mesh = mi.Mesh("lens", n * n, len(faces), props=props, has_vertex_normals=True)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(positions.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(faces.astype(np.uint32).ravel())
    params.update()
    return mesh


def make_scene(n, res):
    def look_at(origin, target):
        return mi.ScalarTransform4f().look_at(origin=origin, target=target, up=[0, 0, 1])

    white = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [1, 1, 1]}}
    black = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0, 0, 0]}}
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": MAX_DEPTH},
        # the camera hangs below the slab, looking down at the floor
        "sensor": {"type": "perspective", "fov": 45, "near_clip": 1, "far_clip": 1000,
                   "to_world": look_at([0, -4.65, 0], [0, -20, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "pixel_format": "rgb",
                            "rfilter": {"type": "gaussian"}}},
        "floor": {"type": "rectangle", "bsdf": white,
                  "to_world": look_at([0, -7, 0], [0, 1, 0]).scale([5, 5, 5])},
        "entry": {"type": "rectangle", "bsdf": glass(), "to_world": look_at([0, 0.2, 0], [0, 1, 0])},
        "lens": exit_face(n),
        # a 2 x 2 light that shines straight down only: nearly the sun
        "light": {"type": "rectangle", "to_world": look_at([0, 5, 0], [0, 0, 0]), "bsdf": black,
                  "emitter": {"type": "directionalarea",
                              "radiance": {"type": "rgb", "value": [0.8, 0.8, 0.8]}}},
    })  # fmt: skip


class Heightmap:
    """The exit face's n x n vertices moved down (along the face normal) by heights clipped to
    +-0.01, as in Mitsuba's tutorial (the floor is 7 units away)."""

    def __init__(self, scene, n):
        self.params = mi.traverse(scene)
        self.params.keep(["lens.vertex_positions"])
        self.flat = mi.Float(self.params["lens.vertex_positions"])  # a copy of the flat grid
        self.y = dr.arange(mi.UInt32, n * n) * 3 + 1  # index of each vertex's y coordinate

    def apply(self, heights):
        offset = dr.zeros(mi.Float, dr.width(self.flat))
        dr.scatter(offset, -dr.clip(heights, -0.01, 0.01), self.y)
        self.params["lens.vertex_positions"] = self.flat + offset
        self.params.update()  # also recomputes the vertex normals


def smiley(res):
    """The target: a bright smiley on a dim background, mean 1."""
    y, x = (np.mgrid[0:res, 0:res] + 0.5) / res * 2 - 1
    image = np.full((res, res), 0.2)
    image[np.abs(np.hypot(x, y) - 0.7) < 0.08] = 1.0  # face
    for eye in (-0.28, 0.28):
        image[np.hypot(x - eye, y + 0.25) < 0.12] = 1.0
    image[(np.abs(np.hypot(x, y + 0.05) - 0.42) < 0.07) & (y > 0.12)] = 1.0  # mouth
    image /= image.mean()
    return mi.TensorXf(np.repeat(image[:, :, None], 3, 2).astype(np.float32))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="a small, fast run (a smoke test)")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--photons", type=int, default=100_000)
    parser.add_argument("--spp", type=int, default=4, help="eye paths per pixel and step")
    parser.add_argument("--radius", type=float, default=0.034, help="kernel radius, about a pixel")
    parser.add_argument("--lr", type=float, default=3e-4)
    parser.add_argument("--out", type=Path, default=Path("out/caustic_design"))
    args = parser.parse_args(argv)
    n, res, check_spp = (16, 32, 256) if args.quick else (64, 64, 4096)
    if args.quick:
        args.steps, args.photons, args.radius = 15, 20_000, 0.07

    scene = make_scene(n, res)
    target = smiley(res)
    heightmap = Heightmap(scene, n)
    params = heightmap.params

    opt = mi.ad.Adam(lr=args.lr)
    opt["heights"] = dr.zeros(mi.Float, n * n)
    for step in range(args.steps):
        heightmap.apply(opt["heights"])
        image = photonmap.render(scene, params, method="sppm", photons=args.photons,
                                 spp=args.spp, radius=args.radius, max_depth=MAX_DEPTH,
                                 seed=step)  # fmt: skip
        # scale-independent L2: the light's brightness does not matter
        loss = dr.mean(dr.square(image / dr.mean(dr.detach(image), axis=None) - target), axis=None)
        dr.backward(loss)
        opt.step()
        if step in (args.steps // 2, 3 * args.steps // 4):  # finer steps towards the end
            opt.set_learning_rate(0.5 * opt.learning_rate())
        if step % 25 == 0 or step == args.steps - 1:
            print(f"step {step:4d}  loss {loss.array[0]:.4f}", flush=True)

    with dr.suspend_grad():
        heightmap.apply(opt["heights"])
        ptracer = mi.load_dict({"type": "ptracer", "max_depth": MAX_DEPTH})
        check = mi.render(scene, integrator=ptracer, spp=check_spp, seed=12345)
    args.out.mkdir(parents=True, exist_ok=True)
    check = check / dr.mean(check, axis=None)
    image = image / dr.mean(dr.detach(image), axis=None)
    scale = 1 / np.array(target).max()  # written before returning: not Mitsuba's async default
    for name, picture in (("target", target), ("estimate", image), ("ptracer", check)):
        mi.util.write_bitmap(str(args.out / f"{name}.png"), picture * scale, write_async=False)
    gap = np.ones((res, 2, 3), np.float32)
    side = np.concatenate([np.array(target) * scale, gap, np.array(check) * scale], 1)
    mi.util.write_bitmap(str(args.out / "side_by_side.png"), np.clip(side, 0, 1), write_async=False)
    final = dr.mean(dr.square(check - target), axis=None).array[0]  # with the check's noise
    print(f"ptracer check: loss {final:.4f}; images in {args.out}")
    return final


if __name__ == "__main__":
    main()
