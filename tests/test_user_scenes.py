"""Every method on files written as a user writes them (``tests/scenes/*.xml``) against Mitsuba's
own integrator on the same file at the file's own settings (issue 20, item 5).

Each (file, method) pair runs ``photonmap render FILE --method M`` (in process, seed 0, the small
budgets of ``user_scenes.TEST_SETS``) and compares the image with Mitsuba's image of the file
(``user_scenes.reference``: the file's ``<integrator>``, 2048 spp or a cached image with more):

* the mean brightness within 5 %,
* the relative RMSE of 4 × 4-block means below the case's bound. A bound is twice what was
  measured over seeds 0–2 at these budgets (``python tests/user_scenes.py calibrate``; the
  numbers are in ``benchmarks/results/user_scenes_calibration.json``): twice the worst seed's
  error where the method renders the file right today; where it does not, twice the error an
  unbiased render with the measured noise would reach, √(noise² + reference noise²) (at least
  0.05), which is what it should meet once fixed.

A pair that fails today is marked ``xfail(strict=False)`` with what is wrong. The volume method
refuses a scene without fog by design: that pair checks the refusal (exit status 2, one
``error:`` line). Every pair also checks that the command ends cleanly: an image, or exit status
2 with one ``error:`` line — never a traceback.

Run time here (2 shared cores): about 2–3 minutes for the file on a fresh checkout (Dr.Jit's
kernel cache cold, references rendered), ≈ 1½ minutes warm.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np
import pytest

import user_scenes as us

BRIGHTNESS = 0.05  # |mean ratio − 1|


@dataclass(frozen=True)
class Renders:
    """The method must render the file: brightness within 5 %, 4 × 4-block error < ``bound``;
    ``wrong``: what is wrong today (the pair is xfail)."""

    bound: float
    wrong: str | None = None


@dataclass(frozen=True)
class Refuses:
    """The method declines the file by design: exit status 2 and one ``error:`` line that says
    ``says``."""

    says: str


NO_FOG = Refuses("the scene has no fog")
VACUUM = "renders the media as vacuum (it warns)"

CASES: dict[str, dict[str, Renders | Refuses]] = {
    "box_max_depth3": {
        "volume": NO_FOG,
        "surface": Renders(0.06, "ignores the file's max_depth 3 (renders more bounces): +8.5 %"),
        "screen": Renders(0.092, "ignores the file's max_depth 3: +7 %"),
        "sppm": Renders(0.13, "ignores the file's max_depth 3 (renders more bounces): +9 %"),
    },
    "bump_normal": {
        "volume": NO_FOG,
        "surface": Renders(0.041),
        "screen": Renders(0.05, "ignores the normal map and the bump map (flat wall): +8 %"),
        "sppm": Renders(0.033),
    },
    "crop_plastic_point": {
        "volume": NO_FOG,
        "surface": Renders(
            0.065,
            "block error 0.061-0.071 (seeds 0-2) in the window of the plastic balls; the crop "
            "is right (the same window of the full film's render has the same error)",
        ),
        "screen": Renders(0.13),  # 0.124-0.129 (seeds 0-2)
        "sppm": Renders(0.11),  # 0.029-0.039
    },
    "fog_null_point": {
        "volume": Renders(0.055, "does not render the diffuse floor and block (it warns): −27 %"),
        "surface": Renders(
            0.12,
            "the point light without <ref name='medium'> inside the fog "
            "box shines as in vacuum: the fog gets no photons, −32 % "
            "(with the reference: 0.99)",
        ),
        "screen": Renders(0.055, VACUUM + ": −67 %"),
        "sppm": Renders(
            0.11,
            "the point light without <ref name='medium'> inside the fog box "
            "shines as in vacuum: −37 % (with the reference: 0.99)",
        ),
    },
    "fog_thindielectric_area": {
        "volume": Renders(
            0.05, "renders the fog only: the floor, ball and lamp are not seen, −44 %"
        ),
        "surface": Renders(0.45, "−18 % (fog in a thindielectric case lit from inside)"),
        "screen": Renders(
            0.22,
            "refuses: 'the area light ... lies inside geometry' (the "
            "light is inside the glass case, in the fog)",
        ),
        "sppm": Renders(0.22),  # −3 … −5 %: at the edge of the 5 %
    },
    "glass_ball_medium": {
        "volume": Renders(0.05, "renders only the medium in the ball (no floor): −60 %"),
        "surface": Renders(
            0.088,
            "the ball's scattering interior (medium inside a dielectric) is too bright: +13 %",
        ),
        "screen": Renders(0.05, VACUUM + ": +8 %"),
        "sppm": Renders(
            0.061,
            "the ball's scattering interior (medium inside a dielectric) is too bright: +12 %",
        ),
    },
    "glass_slabs_depth24": {
        "volume": NO_FOG,
        "surface": Renders(
            0.76,
            "stops at 8 bounces though the file asks max_depth 24: the "
            "floor under the slabs is black, −38 %",
        ),
        "screen": Renders(0.13, "the floor under the glass slabs is black: −71 %"),
        "sppm": Renders(
            0.32,
            "stops at 8 bounces though the file asks max_depth 24: the floor "
            "under the slabs is black, −33 %",
        ),
    },
    "heterogeneous_smoke": {
        "volume": Renders(0.05, "renders the smoke only: the floor is not seen, −74 %"),
        "surface": Renders(0.13),
        "screen": Renders(0.05, VACUUM + ": −19 %"),
        "sppm": Renders(0.15),
    },
    "hide_emitters": {
        "volume": NO_FOG,
        "surface": Renders(0.18, "ignores hide_emitters: draws the lamp and the sky (4.3× bright)"),
        "screen": Renders(
            0.05,
            "ignores hide_emitters (draws the lamp and the sky) and the sky's light (it warns)",
        ),
        "sppm": Renders(0.22, "ignores hide_emitters: draws the lamp and the sky (4.3× bright)"),
    },
    "mask_blend": {
        "volume": NO_FOG,
        "surface": Renders(0.36),
        "screen": Renders(0.12, "draws the 70 %-transparent mask card opaque"),
        "sppm": Renders(0.077, "draws the 70 %-transparent mask card opaque: −17 %"),
    },
    "metals": {
        "volume": NO_FOG,
        "surface": Renders(0.16),
        "screen": Renders(
            0.099, "the rough copper ball comes out a diffuse white; block error 0.93"
        ),
        "sppm": Renders(0.17),
    },
    "nested_aov_volpath": {
        "volume": Renders(0.05, "renders the fog only: floor, glass ball and lamp not seen, −72 %"),
        "surface": Renders(0.28),
        "screen": Renders(0.05, VACUUM + ": block error 2.3"),
        "sppm": Renders(0.2),
    },
    "roughglass_medium_env": {  # bounds not measured: no method renders this file today
        "volume": Renders(0.15, "refuses the roughdielectric boundary of the medium"),
        "surface": Renders(
            0.15,
            "crashes: RuntimeError 'jit_var_mod ... operands have "
            "incompatible sizes (0, 1)' (constant sky + medium in a "
            "roughdielectric)",
        ),
        "screen": Renders(0.15, "refuses a scene lit by the environment only"),
        "sppm": Renders(
            0.15, "crashes: RuntimeError 'jit_var_mod ... operands have incompatible sizes (0, 1)'"
        ),
    },
    "sensor_in_fog": {
        "volume": Renders(
            0.15, "refuses: fog around the sensor only ('no refractive or medium-bearing shape')"
        ),
        "surface": Renders(0.16),
        "screen": Renders(0.08, VACUUM + ", and lights with the point light only: −19 %"),
        "sppm": Renders(0.18),
    },
    "spot_gaussian_film": {
        "volume": NO_FOG,
        "surface": Renders(0.17),
        "screen": Renders(0.45),  # 0.47 with the film's filter, 0.51 without (seed 0)
        "sppm": Renders(0.11),
    },
    "thin_rough_glass_envmap": {
        "volume": NO_FOG,
        "surface": Renders(
            0.12,
            "−10 %: the envmap's light through the rough glass ball and onto the floor is short",
        ),
        "screen": Renders(0.29, "refuses a scene lit by the environment only"),
        "sppm": Renders(0.29),
    },
}

PAIRS = [(name, method) for name in CASES for method in us.METHODS]


def _param(name, method, marks_for):
    marks = marks_for(CASES[name][method])
    return pytest.param(name, method, id=f"{name}-{method}", marks=marks)


def _xfail(case):
    if isinstance(case, Renders) and case.wrong:
        return [pytest.mark.xfail(strict=False, reason=case.wrong)]
    return []


def _xfail_crash(case):
    if isinstance(case, Renders) and case.wrong and case.wrong.startswith("crashes"):
        return [pytest.mark.xfail(strict=False, reason=case.wrong)]
    return []


@cache
def reference(name: str) -> np.ndarray:
    return us.reference(us.scene_path(name), us.TEST_REF_SPP)[0]


@cache
def run(name: str, method: str) -> us.Run:
    return us.render_inprocess(us.scene_path(name), method, us.test_sets(name, method), seed=0)


def test_the_corpus_is_complete():
    """Every file has its cases, and the files are small user-written XML."""
    files = {p.stem for p in us.scene_files()}
    assert files == set(CASES)
    assert len(files) >= 14
    for path in us.scene_files():
        text = path.read_text()
        assert '<scene version="3.0.0">' in text and "<!--" in text and "<integrator" in text
        assert path.stat().st_size < 8000


@pytest.mark.parametrize(
    ("name", "method"),
    [_param(n, m, _xfail) for n, m in PAIRS if isinstance(CASES[n][m], Renders)],
)
def test_renders_like_mitsuba(name, method):
    case = CASES[name][method]
    result = run(name, method)
    assert result.returncode == 0, f"{method} on {name}: {result.error}"
    ref = reference(name)
    assert result.image.shape == ref.shape
    assert np.all(np.isfinite(result.image))
    errors = us.errors(result.image, ref)
    assert abs(errors["brightness"] - 1) < BRIGHTNESS, errors
    assert errors["block_rel_rmse"] < case.bound, errors


@pytest.mark.parametrize(
    ("name", "method"),
    [_param(n, m, lambda c: []) for n, m in PAIRS if isinstance(CASES[n][m], Refuses)],
)
def test_refuses_in_one_line(name, method):
    result = run(name, method)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.returncode == 2 and result.image is None
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    assert CASES[name][method].says in lines[0]


@pytest.mark.parametrize(("name", "method"), [_param(n, m, _xfail_crash) for n, m in PAIRS])
def test_ends_cleanly(name, method):
    """An image, or exit status 2 with one ``error:`` line (a refusal): never a traceback."""
    result = run(name, method)
    if result.returncode == 0:
        assert result.image is not None
        return
    errors = [line for line in result.stderr.splitlines() if line.startswith("error: ")]
    assert result.returncode == 2 and len(errors) == 1, result.error


def test_benchmark_script_writes_its_table(tmp_path):
    """``benchmarks/user_scenes.py`` end to end on one file and one method (a refusal: no
    render), with a cheap reference."""
    import importlib.util
    import json

    path = us.REPO / "benchmarks" / "user_scenes.py"
    spec = importlib.util.spec_from_file_location("benchmarks_user_scenes", path)
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    args = ["--scenes", "box_max_depth3", "--methods", "volume,screen", "--ref-spp", "256"]
    args += ["--mitsuba-spp", "16", "--out-dir", str(tmp_path), "--name", "quick"]
    result = script.main(args)
    data = json.loads((tmp_path / "quick.json").read_text())
    assert data["scenes"]["box_max_depth3"]["methods"]["volume"]["status"] == "refused"
    screen = data["scenes"]["box_max_depth3"]["methods"]["screen"]
    assert screen["status"] == "ok" and 0.5 < screen["brightness"] < 2
    assert data["machine"]["load_average"] and result["name"] == "quick"
    table = (tmp_path / "quick.md").read_text()
    assert "| box_max_depth3 |" in table and "exit 2 [1]" in table and "load average" in table
