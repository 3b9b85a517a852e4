"""The tests' cache of Mitsuba renders (``tests/mitsuba_reference.py``): a cached image is what
``mi.render`` gave, and anything that changes the render changes its name."""

import mitsuba as mi
import numpy as np
import pytest

import mitsuba_reference as ref


def box(red=0.57, size=16):
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=size, height=size)
    d["red"]["reflectance"]["value"] = [red, 0.04, 0.04]
    return mi.load_dict(d)


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setattr(ref, "CACHE", tmp_path)
    return tmp_path


def test_a_cached_render_is_mitsubas_render(cache):
    """Read back bit for bit; against a fresh render, equal up to the order in which Mitsuba's
    threads add samples into the film."""
    path = mi.load_dict({"type": "path", "max_depth": 4})
    fresh = np.array(mi.render(box(), integrator=path, spp=8, seed=3))
    first = ref.render(box(), path, spp=8, seed=3)
    assert len(list(cache.glob("*.npy"))) == 1
    again = ref.render(box(), path, spp=8, seed=3)
    assert len(list(cache.glob("*.npy"))) == 1
    assert first.dtype == again.dtype == fresh.dtype and first.shape == fresh.shape
    assert np.array_equal(again, first)
    np.testing.assert_allclose(first, fresh, rtol=1e-5, atol=1e-7)


def test_what_changes_the_render_changes_its_name():
    path = mi.load_dict({"type": "path", "max_depth": 4})
    name = ref.digest(box(), path, 8, 3)
    assert ref.digest(box(), path, 8, 3) == name  # the same scene built again
    changed = [
        ref.digest(box(red=0.5), path, 8, 3),  # a texture value (mi.traverse)
        ref.digest(box(size=12), path, 8, 3),  # the film (its description)
        ref.digest(box(), mi.load_dict({"type": "path", "max_depth": 5}), 8, 3),
        ref.digest(box(), None, 8, 3),
        ref.digest(box(), path, 16, 3),
        ref.digest(box(), path, 8, 4),
    ]
    assert len({name, *changed}) == 1 + len(changed)
    scene = box()
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith("vertex_positions"))
    params[key] = params[key] + 1e-6  # below the description's printed precision
    params.update()
    assert ref.digest(scene, path, 8, 3) != name
