"""A glass ball under a narrow spot light over a diffuse floor, the camera on the floor and the
caustic, not the ball (Mitsuba's ``ptracer`` renders every pixel): the caustic scene of the
surface and SPPM tests."""

import mitsuba as mi

T = mi.ScalarTransform4f


def spot_caustic_scene(floor: float, res: int = 48) -> mi.Scene:
    """A glass ball (radius 1, n = 1.5) at the origin lit by a 3.5° spot light 20 above it, over a
    diffuse floor (albedo 0.5) at height ``floor``; a ``res``² camera looks at the floor."""
    return mi.load_dict(
        {
            "type": "scene",
            "ball": {
                "type": "sphere",
                "radius": 1.0,
                "bsdf": {"type": "dielectric", "int_ior": 1.5},
            },
            "floor": {
                "type": "rectangle",
                "to_world": T().translate([0, floor, 0]).rotate([1, 0, 0], -90).scale(4),
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}},
            },
            "light": {
                "type": "spot",
                "cutoff_angle": 3.5,
                "beam_width": 3.4,
                "intensity": 100.0,
                "to_world": T().look_at(origin=[0, 20, 0], target=[0, 0, 0], up=[0, 0, 1]),
            },
            "sensor": {
                "type": "perspective",
                "fov": 30,
                "to_world": T().look_at(origin=[0, 0.5, 6], target=[0, floor, 0], up=[0, 1, 0]),
                "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
            },
        }
    )
