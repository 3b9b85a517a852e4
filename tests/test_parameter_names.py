"""One vocabulary across the methods: the photon budget is ``photons``, the gather radius is
``radius`` in scene units, the path length is ``max_depth`` with Mitsuba's meaning. Old names
keep working for one release: each is translated to the current one with a
:class:`~photonmap.core.errors.DeprecatedParameter` warning, in Python, on the command line and
as a Mitsuba plugin property."""

from __future__ import annotations

import dataclasses

import mitsuba as mi
import pytest
from typer.testing import CliRunner

from photonmap import METHODS, ParameterError
from photonmap.cli import app
from photonmap.core.errors import DeprecatedParameter
from photonmap.core.params import parameter_names, updated

OLD = [  # method, old name and value, current name and value
    ("sppm", "photons_per_iteration", 5000, "photons", 5000),
    ("surface", "max_radius", 0.25, "radius", 0.25),
    ("volume", "max_radius", 0.25, "radius", 0.25),
    ("screen", "light_res", 20, "photons", 400),
]


@pytest.mark.parametrize(("method", "old", "old_value", "new", "new_value"), OLD)
def test_an_old_name_sets_the_current_parameter_with_a_warning(
    method, old, old_value, new, new_value
):
    params_type = METHODS[method].params
    assert old in parameter_names(params_type) and old not in {
        f.name for f in dataclasses.fields(params_type)
    }
    with pytest.warns(DeprecatedParameter, match=f"'{old}' is now '{new}'"):
        params = updated(params_type(), {old: old_value}, method)
    assert params == updated(params_type(), {new: new_value}, method)
    with pytest.raises(ParameterError, match=f"{old} is the old name of {new}; give {new} only"):
        updated(params_type(), {old: old_value, new: new_value}, method)


def test_the_photon_budget_gather_radius_and_path_length_have_one_name():
    for method in ("surface", "sppm", "screen", "volume"):
        names = {f.name for f in dataclasses.fields(METHODS[method].params)}
        assert "photons" in names and "radius" in names, method
        if method != "volume":  # the volume method renders paths of any length
            assert "max_depth" in names, method


def test_an_old_name_works_on_the_command_line(tmp_path):
    result = CliRunner().invoke(app, ["render", "cornell_ispm", "-o", str(tmp_path / "x.exr"),
                                      "--width", "32", "--set", "light_res=20"])  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "warning: the screen parameter 'light_res' is now 'photons'" in result.output


def test_an_old_name_works_as_a_plugin_property():
    with pytest.warns(DeprecatedParameter, match="'photons_per_iteration' is now 'photons'"):
        integrator = mi.load_dict({"type": "sppm", "photons_per_iteration": 1000})
    assert integrator.params == {"photons": 1000}  # translated once, when the plugin is made


def test_an_old_name_works_in_a_pipeline_keyword():
    with pytest.warns(DeprecatedParameter, match="'photons_per_iteration' is now 'photons'"):
        pipe = METHODS["sppm"].pipeline("examples/cornell_box.xml", photons_per_iteration=1000)
    assert pipe.params.photons == 1000
