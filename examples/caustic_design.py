"""Caustic design with differentiable photon mapping.

A glass surface under a light casts a caustic on a white floor. The surface is a grid of vertices
that we push up or down (a heightmap); Adam moves them until the caustic shows a target picture:
here a smiley drawn with NumPy. Each step renders the caustic with
``photonmap.render(scene, params, ...)`` (photons traced from the light through the glass,
density-estimated on the floor, differentiable in the vertex positions) and backpropagates an
L2 loss. At the end Mitsuba renders the optimised surface, as an independent check. Three
set-ups (``--problem``):

- ``tutorial`` — Mitsuba 3's caustic-design tutorial: a glass slab whose exit face is the
  heightmap, under a ``directionalarea`` light (nearly the sun), and a camera between slab and
  floor that sees the floor directly. Checked with Mitsuba's ``ptracer`` (``path`` would have
  to hit a light that shines in one direction only).
- ``pool`` — a water surface (the heightmap, ``dielectric`` of index 1.33) over a pool floor one
  unit below, under a small area light, seen from above *through the water*: no light path can be
  connected to the camera, so ``ptracer`` renders nothing. Checked with Mitsuba's ``path``.
- ``window`` — the tutorial's slab under a small area light, the floor two units below it, and the
  camera looking at the floor through a pane of glass just in front of it (a window): again no
  connection to the camera. Checked with ``path``.

The glass everywhere has no specular reflection (all light goes through), as in the tutorial.

    .venv/bin/python examples/caustic_design.py [--problem pool] [--quick] [--steps 300]

Writes ``target.png``, ``estimate.png`` (the last photon-mapped image), ``check.png`` (Mitsuba's
render of the result) and ``side_by_side.png`` (target | check) in ``--out``
(``out/caustic_design/<problem>`` by default).
"""

import argparse
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

import photonmap  # selects the llvm_ad_rgb variant

MAX_DEPTH = 4  # tutorial: light -> slab entry -> slab exit -> floor -> camera
WHITE = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [1, 1, 1]}}
BLACK = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0, 0, 0]}}


def glass(ior=1.5):
    """The tutorial's glass: no specular reflection (all light goes through)."""
    return {"type": "dielectric", "int_ior": ior, "ext_ior": 1.0,
            "specular_reflectance": {"type": "spectrum", "value": 0.0}}  # fmt: skip


def grid_mesh(name, n, half, facing_up, ior=1.5):
    """An n x n vertex grid over [-half, half]^2 at y = 0, of glass of index ``ior``, its faces
    facing up (+y) or down."""
    u, v = np.meshgrid(np.linspace(-half, half, n), np.linspace(-half, half, n), indexing="ij")
    positions = np.stack([u, np.zeros_like(u), v], -1)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    faces = np.concatenate([np.stack([a, a + n, a + 1], 1), np.stack([a + 1, a + n, a + n + 1], 1)])
    if facing_up:
        faces = faces[:, ::-1]
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(glass(ior))
    mesh = mi.Mesh(name, n * n, len(faces), props=props, has_vertex_normals=True)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(positions.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(np.ascontiguousarray(faces).astype(np.uint32).ravel())
    params.update()
    return mesh


def exit_face(n):
    """The tutorial slab's exit face: an n x n vertex grid over [-1, 1]^2 at y = 0, facing down."""
    return grid_mesh("lens", n, 1.0, facing_up=False)


def look_at(origin, target, up=(0, 0, 1)):
    return mi.ScalarTransform4f().look_at(origin=origin, target=target, up=list(up))


def camera(origin, target, fov, res, up=(0, 0, 1), near_clip=0.01):
    return {"type": "perspective", "fov": fov, "near_clip": near_clip, "far_clip": 1000,
            "to_world": look_at(origin, target, up),
            "film": {"type": "hdrfilm", "width": res, "height": res, "pixel_format": "rgb",
                     "rfilter": {"type": "gaussian"}}}  # fmt: skip


def floor(y, half):
    return {"type": "rectangle", "bsdf": WHITE,
            "to_world": look_at([0, y, 0], [0, 1, 0]).scale([half, half, half])}  # fmt: skip


def small_light(y, size, radiance):
    """A ``size`` x ``size`` area light at height ``y``, shining down."""
    return {"type": "rectangle", "bsdf": BLACK,
            "to_world": look_at([0, y, 0], [0, 0, 0]).scale([size / 2, size / 2, 1]),
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [radiance] * 3}}}  # fmt: skip


def make_scene(n, res):
    """The tutorial set-up (module docstring)."""
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": MAX_DEPTH},
        # the camera hangs below the slab, looking down at the floor
        "sensor": camera([0, -4.65, 0], [0, -20, 0], 45, res, near_clip=1),
        "floor": floor(-7, 5),
        "entry": {"type": "rectangle", "bsdf": glass(), "to_world": look_at([0, 0.2, 0], [0, 1, 0])},
        "lens": exit_face(n),
        # a 2 x 2 light that shines straight down only: nearly the sun
        "light": {"type": "rectangle", "to_world": look_at([0, 5, 0], [0, 0, 0]), "bsdf": BLACK,
                  "emitter": {"type": "directionalarea",
                              "radiance": {"type": "rgb", "value": [0.8, 0.8, 0.8]}}},
    })  # fmt: skip


def make_pool(n, res):
    """The pool (module docstring): water over [-1.3, 1.3]^2 at y = 0, the floor at y = -1, a
    0.3 x 0.3 light at y = 3 and the camera at y = 2, both straight above."""
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 4},  # light, water, floor, water, camera
        "sensor": camera([0, 2, 0], [0, -10, 0], 45, res),
        "floor": floor(-1, 3),
        "water": grid_mesh("water", n, 1.3, facing_up=True, ior=1.33),
        "light": small_light(3, 0.3, 10.0),
    })  # fmt: skip


def make_window(n, res):
    """The window (module docstring): the tutorial's slab, a 0.2 x 0.2 light at y = 4, the
    floor at y = -2, and the camera below the slab at (0, -0.5, 1.2) looking down at
    (0, -2, 0) through a pane 0.03 thick, 0.3 in front of it."""
    origin, target = np.array([0, -0.5, 1.2]), np.array([0, -2.0, 0])
    forward = (target - origin) / np.linalg.norm(target - origin)

    def pane(distance, facing):
        centre = origin + distance * forward
        to_world = look_at(centre, centre + facing * forward, (0, 1, 0)).scale([0.25] * 3)
        return {"type": "rectangle", "bsdf": glass(), "to_world": to_world}

    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 6},  # light, slab x2, floor, pane x2, camera
        "sensor": camera(origin, target, 40, res, up=(0, 1, 0)),
        "floor": floor(-2, 4),
        "entry": {"type": "rectangle", "bsdf": glass(), "to_world": look_at([0, 0.2, 0], [0, 1, 0])},
        "lens": exit_face(n),
        "pane_near": pane(0.3, -1),
        "pane_far": pane(0.33, 1),
        "light": small_light(4, 0.2, 100.0),
    })  # fmt: skip


class Heightmap:
    """The heightmap's n x n vertices of the mesh ``key`` (``lens``: the slab's exit face, moved
    down; ``water``: moved up), clipped to +-``clip`` (the tutorial's 0.01, its floor 7 units
    away)."""

    def __init__(self, scene, n, key="lens", clip=0.01):
        self.key, self.clip = f"{key}.vertex_positions", clip
        self.sign = 1.0 if key == "water" else -1.0
        self.params = mi.traverse(scene)
        self.params.keep([self.key])
        self.flat = mi.Float(self.params[self.key])  # a copy of the flat grid
        self.y = dr.arange(mi.UInt32, n * n) * 3 + 1  # index of each vertex's y coordinate

    def apply(self, heights):
        offset = dr.zeros(mi.Float, dr.width(self.flat))
        dr.scatter(offset, self.sign * dr.clip(heights, -self.clip, self.clip), self.y)
        self.params[self.key] = self.flat + offset
        self.params.update()  # also recomputes the vertex normals


@dataclass(frozen=True)
class Problem:
    """A design problem: its scene, the mesh the heightmap moves and its clip, the path depth,
    Mitsuba's integrator that renders it (the check) and a learning rate and kernel radius that
    suit it."""

    make: Callable
    key: str
    clip: float
    max_depth: int
    check: str
    lr: float
    radius: float  # kernel radius in scene units, about a pixel on the floor of a 64^2 film


PROBLEMS = {
    "tutorial": Problem(make_scene, "lens", 0.01, MAX_DEPTH, "ptracer", 3e-4, 0.034),
    "pool": Problem(make_pool, "water", 0.1, 4, "path", 3e-3, 0.035),
    "window": Problem(make_window, "lens", 0.03, 6, "path", 1e-3, 0.03),
}


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


def check_render(scene, problem, spp, seed):
    """Mitsuba's own render of ``scene`` with the problem's integrator (``ptracer`` or ``path``)."""
    integrator = mi.load_dict({"type": problem.check, "max_depth": problem.max_depth})
    return mi.render(scene, integrator=integrator, spp=spp, seed=seed)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--problem", choices=sorted(PROBLEMS), default="tutorial")
    parser.add_argument("--quick", action="store_true", help="a small, fast run (a smoke test)")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--photons", type=int, default=100_000)
    parser.add_argument("--spp", type=int, default=4, help="eye paths per pixel and step")
    parser.add_argument("--radius", type=float, default=None,
                        help="kernel radius, about a pixel (default: the problem's)")  # fmt: skip
    parser.add_argument("--lr", type=float, default=None, help="default: the problem's")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    problem = PROBLEMS[args.problem]
    radius, lr = args.radius or problem.radius, args.lr or problem.lr
    out = args.out or Path("out/caustic_design") / args.problem
    n, res, check_spp = (16, 32, 256) if args.quick else (64, 64, 4096)
    if problem.check == "path":  # path finds the light through the glass by chance only
        check_spp *= 16
    if args.quick:
        args.steps, args.photons, radius = 15, 20_000, 2 * radius

    scene = problem.make(n, res)
    target = smiley(res)
    heightmap = Heightmap(scene, n, problem.key, problem.clip)
    params = heightmap.params

    opt = mi.ad.Adam(lr=lr)
    opt["heights"] = dr.zeros(mi.Float, n * n)
    for step in range(args.steps):
        heightmap.apply(opt["heights"])
        image = photonmap.render(scene, params, method="sppm", photons=args.photons,
                                 spp=args.spp, radius=radius, max_depth=problem.max_depth,
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
        check = check_render(scene, problem, check_spp, 12345)
    out.mkdir(parents=True, exist_ok=True)
    check = check / dr.mean(check, axis=None)
    image = image / dr.mean(dr.detach(image), axis=None)
    scale = 1 / np.array(target).max()  # written before returning: not Mitsuba's async default
    for name, picture in (("target", target), ("estimate", image), ("check", check)):
        mi.util.write_bitmap(str(out / f"{name}.png"), picture * scale, write_async=False)
    gap = np.ones((res, 2, 3), np.float32)
    side = np.concatenate([np.array(target) * scale, gap, np.array(check) * scale], 1)
    mi.util.write_bitmap(str(out / "side_by_side.png"), np.clip(side, 0, 1), write_async=False)
    final = dr.mean(dr.square(check - target), axis=None).array[0]  # with the check's noise
    print(f"{problem.check} check: loss {final:.4f}; images in {out}")
    return final


if __name__ == "__main__":
    main()
