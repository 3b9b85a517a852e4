"""Built-in scenes and scene loading (docs/DESIGN.md "Scenes").

A scene is a Mitsuba 3 scene: a built-in name from :data:`SCENES`, an XML file, a scene dict or a
loaded ``mi.Scene``. Built-ins also carry the photonmap pipeline they are made for
(:attr:`Builtin.pipeline`) and the pipeline settings they want (:attr:`Builtin.defaults`).
"""

from __future__ import annotations

import inspect
import os
from collections.abc import Callable
from dataclasses import dataclass, field

import mitsuba as mi

from ..core.errors import ParameterError, SceneError
from ..core.params import parameter_names
from ..core.scene_info import check_bsdfs_evaluate
from . import bushes, cornell, ispm, volume_scenes


@dataclass(frozen=True)
class Builtin:
    """A built-in scene: ``build(**params)`` returns a dict for ``mi.load_dict``; ``pipeline`` is
    the ``--method`` it is made for and ``defaults`` are the pipeline parameters the scene is meant
    to be rendered with."""

    name: str
    description: str
    build: Callable[..., dict]
    defaults: dict = field(default_factory=dict)
    pipeline: str = "volume"

    @property
    def params(self) -> dict:
        """The scene parameters ``build`` accepts, with their default values."""
        return {k: p.default for k, p in inspect.signature(self.build).parameters.items()}


SCENES: dict[str, Builtin] = {
    b.name: b
    for b in (
        Builtin(
            "glass_sphere_fog",
            "SPHERE: glass ball (n 1.5, r 32 voxels) in grey fog, point light above (Sun Fig 6)",
            volume_scenes.glass_sphere_fog,
            volume_scenes.SPHERE_DEFAULTS,
        ),
        Builtin(
            "perlin_cube",
            "CUBE: turned 60-voxel glass cube, n and σ_s perturbed by Perlin noise (Pfeuti Fig 4.9)",
            volume_scenes.perlin_cube,
            volume_scenes.CUBE_DEFAULTS,
        ),
        Builtin(
            "mesh_in_fog",
            "MESH: glass trefoil-knot mesh in fog (params: triangles, extent; Sun Table 1)",
            volume_scenes.mesh_in_fog,
            volume_scenes.MESH_DEFAULTS,
        ),
        Builtin(
            "cornell_steinhurst",
            "Steinhurst Fig 1.2: Cornell box, ceiling light, mirror and glass spheres (caustic)",
            cornell.cornell_steinhurst,
            pipeline="surface",
        ),
        Builtin(
            "cornell_spot_indirect",
            "Steinhurst Fig 1.2 b: Cornell box lit only by a spot light aimed at a white ceiling disk",
            cornell.cornell_spot_indirect,
            pipeline="surface",
        ),
        Builtin(
            "cornell_glossy_floor",
            "Steinhurst Fig 7.5: Cornell box, Lambertian + glossy floor, checkerboard back wall "
            "(params: roughness, glossy)",
            cornell.cornell_glossy_floor,
            pipeline="surface",
        ),
        Builtin(
            "cornell_bushes",
            "Steinhurst Fig 5.5: Cornell box with bushes of many small diffuse leaves "
            "(params: bushes, leaves, seed)",
            bushes.cornell_bushes,
            pipeline="surface",
        ),
        Builtin(
            "cornell_ispm",
            "Yao Fig 5.1: Cornell box with the short and tall blocks, lit by a spot light",
            ispm.cornell_ispm,
            pipeline="screen",
        ),
        Builtin(
            "cornell_glass_sphere",
            "Yao Tab 1: Cornell box, glass sphere (η 1.5) under a spot light: refractive caustic",
            ispm.cornell_glass_sphere,
            pipeline="screen",
        ),
        Builtin(
            "cornell_mesh",
            "Yao Tab 1 Buddha/dragon/bunny rows: Cornell box, diffuse watertight mesh, spot light "
            "(params: triangles)",
            ispm.cornell_mesh,
            pipeline="screen",
        ),
    )
}


def list_scenes() -> list[Builtin]:
    """The built-in scenes, in registration order."""
    return list(SCENES.values())


def load_with_sensor(scene, params_type, params: dict) -> tuple[mi.Scene, mi.Sensor, dict]:
    """:func:`load_scene` for a pipeline that renders from the scene's first sensor: ``params``
    split into the fields of the dataclass ``params_type`` (returned) and scene parameters
    (passed to :func:`load_scene`); a scene without a sensor is refused."""
    own = parameter_names(params_type)
    mi_scene, _ = load_scene(scene, **{k: v for k, v in params.items() if k not in own})
    if not mi_scene.sensors():
        raise ParameterError("the scene has no sensor (camera) to render from")
    return mi_scene, mi_scene.sensors()[0], {k: v for k, v in params.items() if k in own}


def load_scene(scene, **params) -> tuple[mi.Scene, dict]:
    """Load a scene; return it with the pipeline defaults it wants (empty unless built-in).

    ``scene`` is a built-in name, an XML path, a Mitsuba scene dict or an ``mi.Scene``. For a
    built-in, ``params`` named like one of its defaults override that default and the others go
    to its ``build``; for an XML file they fill its ``$name`` parameters. A scene whose BSDFs
    Mitsuba cannot evaluate is refused (:func:`~photonmap.core.scene_info.check_bsdfs_evaluate`).
    """
    loaded, defaults = _scene_and_defaults(scene, **params)
    check_bsdfs_evaluate(loaded)
    return loaded, defaults


def _scene_and_defaults(scene, **params) -> tuple[mi.Scene, dict]:
    if isinstance(scene, mi.Scene | dict):
        if params:
            raise ParameterError(
                f"scene parameters {sorted(params)} apply only to built-in scenes and XML files"
            )
        return (scene if isinstance(scene, mi.Scene) else _load(mi.load_dict, scene, "dict")), {}
    if not isinstance(scene, str | os.PathLike):
        raise SceneError(
            f"a scene is a built-in name ({', '.join(SCENES)}), the path of a Mitsuba 3 XML "
            f"file, a scene dict or an mi.Scene; got {type(scene).__name__}"
        )
    name = os.fspath(scene)
    if name in SCENES:
        builtin = SCENES[name]
        defaults = {**builtin.defaults}
        build = {}
        for key, value in params.items():
            if key in defaults:
                defaults[key] = value
            elif key in builtin.params:
                build[key] = value
            else:
                raise ParameterError(
                    f"unknown parameter {key!r} for scene {name!r}; it accepts "
                    f"{sorted(builtin.params)} and pipeline defaults {sorted(defaults)}"
                )
        return _load(mi.load_dict, builtin.build(**build), name), defaults
    if os.path.isfile(name):
        return _load(mi.load_file, name, name, **{k: str(v) for k, v in params.items()}), {}
    raise SceneError(
        f"no built-in scene or scene file named {name!r}; built-in scenes: {', '.join(SCENES)} "
        "(or give the path of a Mitsuba 3 XML file)"
    )


def _load(loader, source, what: str, **kwargs) -> mi.Scene:
    try:
        scene = loader(source, **kwargs)
    except RuntimeError as exc:
        raise SceneError(f"Mitsuba could not load scene {what!r}: {exc}") from exc
    if not isinstance(scene, mi.Scene):
        raise SceneError(f"{what!r} describes a {type(scene).__name__}, not a scene")
    return scene


__all__ = ["SCENES", "Builtin", "list_scenes", "load_scene"]
