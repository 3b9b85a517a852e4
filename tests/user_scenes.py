"""Scenes written as a user writes them (``tests/scenes/*.xml``) and what it takes to judge a
method on them: Mitsuba's own image of each file at the file's own settings (cached), a
method's image of the file through the ``photonmap`` command, and the errors between the two.

The ground truth of a file is ``mi.render(scene)`` with the file's own ``<integrator>`` (a
wrapper such as ``aov`` included: its first three channels are the image), so its
``max_depth``, ``rr_depth``, ``hide_emitters``, film size, crop window and reconstruction
filter all hold. References are rendered in passes of :data:`PASS_SPP` samples with seeds
``0, 1, …`` and kept under ``benchmarks/results/cache/user_scenes/`` (git-ignored), keyed by the
file's content, the assets it reads and Mitsuba's version; a request is served by any cached
image with at least as many samples.

Three files read small generated assets (a height map, a normal map, an environment map, a
density grid)
from ``tests/scenes/assets/`` (git-ignored); :func:`write_assets` writes them, byte for byte the
same every time, and every function here calls it first. From a shell::

    PYTHONPATH=src .venv/bin/python tests/user_scenes.py assets      # write the assets
    PYTHONPATH=src .venv/bin/python tests/user_scenes.py reference FILE [SPP]
    PYTHONPATH=src .venv/bin/python tests/user_scenes.py calibrate [NAMES|all [METHODS]]

``calibrate`` renders (file, method) pairs at the tests' settings over three seeds and states the
bound of each case (:func:`calibrate`); it writes them into
``benchmarks/results/user_scenes_calibration.json`` (a partial run updates its cases). The tests
read nothing from there: their bounds are written out in ``tests/test_user_scenes.py``.
"""

from __future__ import annotations

import hashlib
import os
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import mitsuba_reference

REPO = Path(__file__).resolve().parent.parent
SCENES = REPO / "tests" / "scenes"
ASSETS = SCENES / "assets"
CACHE = REPO / "benchmarks" / "results" / "cache" / "user_scenes"
METHODS = ("volume", "surface", "screen", "sppm", "vcm")
PASS_SPP = 256  # 48 × 48 × 256 samples ≈ 120 MB in flight on the LLVM backend
TEST_REF_SPP = 2048  # references of the tests (a cached image with more samples serves)

# The methods' settings in the tests: small budgets, so that every file renders in a second or
# two here (the film and the file's own settings are never overridden).
TEST_SETS = {
    "volume": {"grid": 48, "photons": 131072},
    "surface": {"photons": 20000, "caustic_photons": 100000, "fg_rays": 4, "spp": 4},
    "screen": {},
    "sppm": {"iterations": 16, "photons": 10000, "spp": 4},
    "vcm": {"iterations": 16, "spp": 1},
}
# with media: more photons (the volume photon map's k-NN density estimate is biased bright at a
# few ten thousand photons: +13 % on the smoke ball at 20k, +2 % at 200k)
TEST_SETS_MEDIA = {"surface": {"photons": 200000}, "sppm": {"photons": 40000, "spp": 1}}
# per file: where the budgets above cost too much (sppm's eye pass through the fog filling a room)
TEST_SETS_FOR = {
    ("sensor_in_fog", "sppm"): {"iterations": 4, "photons": 20000},
    # the surface method's scattered density is precomputed by k-NN at every 4th volume photon:
    # 200k photons fill the room with 310k volume photons (18 s here), 100k with half (7.5 s) at
    # the same error (0.046-0.055 against 0.050-0.057, seeds 0-2)
    ("sensor_in_fog", "surface"): {"photons": 100000},
}


def test_sets(name: str, method: str) -> dict:
    """The ``--set`` values of ``method`` on file ``name`` in the tests."""
    media = TEST_SETS_MEDIA.get(method, {}) if has_media(load(scene_path(name))) else {}
    return {**TEST_SETS[method], **media, **TEST_SETS_FOR.get((name, method), {})}


def scene_files() -> list[Path]:
    """The corpus, sorted by name."""
    return sorted(SCENES.glob("*.xml"))


def scene_path(name: str) -> Path:
    """``tests/scenes/<name>.xml`` (``name`` with or without ``.xml``)."""
    return SCENES / (name if name.endswith(".xml") else f"{name}.xml")


# ------------------------------------------------------------------------------------- assets
def _smoke_grid(n: int = 16) -> np.ndarray:
    """σ_t data of ``heterogeneous_smoke.xml``: a ball of smoke, dense at its centre, falling
    smoothly to zero at radius 0.45 of the grid, rippled along y; shape (z, y, x, 1)."""
    c = (np.arange(n) + 0.5) / n
    z, y, x = np.meshgrid(c, c, c, indexing="ij")
    r = np.sqrt((x - 0.5) ** 2 + (y - 0.45) ** 2 + (z - 0.5) ** 2)
    density = np.clip(1.0 - r / 0.45, 0.0, 1.0) ** 0.7 * (0.75 + 0.25 * np.cos(6 * np.pi * y))
    return density[..., None].astype(np.float32)


def _sky(width: int = 32, height: int = 16) -> np.ndarray:
    """``sky.exr`` of ``thin_rough_glass_envmap.xml``: a latitude-longitude sky, blue at the
    zenith, pale at the horizon, a dark ground, and a 2 × 2-texel sun (radiance 400)."""
    v = (np.arange(height) + 0.5) / height  # 0: zenith, 1: nadir
    up = np.clip(1 - 2 * v, 0, 1)[:, None, None]
    sky = (1 - up) * np.array([0.9, 0.9, 1.0]) + up * np.array([0.25, 0.45, 1.0])
    ground = np.array([0.12, 0.1, 0.08])
    rows = np.where((v < 0.5)[:, None, None], sky, ground)
    image = np.broadcast_to(rows, (height, width, 3)).astype(np.float32).copy()
    image[4:6, 20:22] = 400.0
    return image


def _bumps(n: int = 32) -> np.ndarray:
    """``bumps.exr`` of ``bump_normal.xml``: a smooth height field of rounded bumps in [0, 1]."""
    c = (np.arange(n) + 0.5) / n
    y, x = np.meshgrid(c, c, indexing="ij")
    h = 0.5 + 0.5 * np.sin(4 * np.pi * x) * np.sin(4 * np.pi * y)
    return np.repeat(h[..., None], 3, axis=2).astype(np.float32)  # RGB: bumpmap reads eval_3


def _tile_normals(n: int = 16) -> np.ndarray:
    """``tiles.exr`` of ``bump_normal.xml``: a normal map of 4 × 4 tiles, each tilted by 22°
    towards one of four directions in turn, encoded as (n + 1) / 2."""
    i = np.arange(n) // (n // 4)
    tile = (i[:, None] + 2 * i[None, :]) % 4  # tile index per texel
    dx = np.array([0.4, -0.4, 0.0, 0.0])[tile]
    dy = np.array([0.0, 0.0, 0.4, -0.4])[tile]
    normal = np.stack([dx, dy, np.ones_like(dx)], axis=-1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    return ((normal + 1) / 2).astype(np.float32)


def _write_if_changed(path: Path, data: bytes) -> None:
    if path.exists() and path.read_bytes() == data:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=path.suffix)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.chmod(tmp, 0o644)  # mkstemp makes it private
    os.replace(tmp, path)  # atomic: a concurrent reader sees the old or the new file


def _encoded(writer, suffix: str) -> bytes:
    with tempfile.TemporaryDirectory() as tmp:
        target = os.path.join(tmp, "asset" + suffix)
        writer(target)
        return Path(target).read_bytes()


def write_assets(folder: Path = ASSETS) -> list[Path]:
    """Write the corpus's generated assets into ``folder`` (only what differs); their paths."""
    import mitsuba as mi

    import photonmap  # noqa: F401  (the variant)

    folder = Path(folder)
    out = []
    for name, array in (
        ("sky.exr", _sky()),
        ("bumps.exr", _bumps()),
        ("tiles.exr", _tile_normals()),
    ):
        data = _encoded(lambda p, a=array: mi.Bitmap(a).write(p), ".exr")
        _write_if_changed(folder / name, data)
        out.append(folder / name)
    data = _encoded(lambda p: mi.VolumeGrid(_smoke_grid()).write(p), ".vol")
    _write_if_changed(folder / "smoke.vol", data)
    out.append(folder / "smoke.vol")
    return out


# --------------------------------------------------------------------------------- references
_ASSET = re.compile(r'value="(assets/[^"]+)"')


def scene_key(path: Path) -> str:
    """12 hex digits of the file's text, the assets it reads and Mitsuba's version."""
    import mitsuba as mi

    path = Path(path)
    text = path.read_bytes()
    h = hashlib.sha256(text)
    for asset in sorted(set(_ASSET.findall(text.decode()))):
        h.update((path.parent / asset).read_bytes())
    h.update(mi.__version__.encode())
    return h.hexdigest()[:12]


def load(path: Path):
    """The Mitsuba scene of a corpus file (assets written first)."""
    import mitsuba as mi

    import photonmap  # noqa: F401

    write_assets()
    return mi.load_file(str(path))


def has_media(scene) -> bool:
    from photonmap.core.scene_info import has_media as media

    return media(scene)


def _cached(path: Path, key: str, spp: int) -> tuple[Path, int] | None:
    best = None
    for f in CACHE.glob(f"{path.stem}-{key}-*spp.exr"):
        n = int(f.stem.rsplit("-", 1)[1][:-3])
        if n >= spp and (best is None or n > best[1]):
            best = (f, n)
    return best


def reference(path, spp: int = 4096, cache: bool = True) -> tuple[np.ndarray, dict]:
    """Mitsuba's image of the file at its own settings, ``(height, width, 3)`` float64, and
    ``{"spp", "seconds", "integrator", "cached"}``. A cached image with ``>= spp`` samples
    serves; else it is rendered (passes of :data:`PASS_SPP`, seeds 0, 1, …) and cached."""
    import drjit as dr
    import mitsuba as mi

    path = Path(path)
    scene = load(path)  # writes the assets, which the key reads
    key = scene_key(path)
    integrator = scene.integrator()
    name = integrator.class_name() if integrator is not None else None
    if cache and (hit := _cached(path, key, spp)):
        image = np.array(mi.Bitmap(str(hit[0])), dtype=np.float64)[..., :3]
        return image, {"spp": hit[1], "seconds": 0.0, "integrator": name, "cached": True}
    if integrator is None:  # mi.render refuses such a file; Mitsuba's path plugin defaults
        integrator = mi.load_dict({"type": "path"})
        name = "PathIntegrator (default)"
    total, done, passes = None, 0, 0
    start = time.perf_counter()
    while done < spp:
        n = min(PASS_SPP, spp - done)
        image = mi.render(scene, integrator=integrator, spp=n, seed=passes)
        image = np.array(image, dtype=np.float64)[..., :3]
        dr.sync_thread()
        total = image * n if total is None else total + image * n
        done += n
        passes += 1
    seconds = time.perf_counter() - start
    image = total / done
    if cache:
        CACHE.mkdir(parents=True, exist_ok=True)
        target = CACHE / f"{path.stem}-{key}-{spp}spp.exr"
        fd, tmp = tempfile.mkstemp(dir=CACHE, suffix=".exr")
        os.close(fd)
        mi.Bitmap(image.astype(np.float32)).write(tmp)
        os.chmod(tmp, 0o644)
        os.replace(tmp, target)
    return image, {"spp": spp, "seconds": seconds, "integrator": name, "cached": False}


# ------------------------------------------------------------------------------------ methods
@dataclass
class Run:
    """One ``photonmap render FILE --method M`` run."""

    returncode: int
    seconds: float
    image: np.ndarray | None = None
    error: str | None = None  # the last line of stderr when the run failed
    stderr: str = ""
    warnings: list[str] = field(default_factory=list)

    @property
    def refused(self) -> bool:
        """Exit status 2 with an ``error:`` line: the method declined the scene."""
        return self.returncode == 2 and (self.error or "").startswith("error:")


_EXCEPTION = re.compile(r"^[A-Za-z_][\w.]*(Error|Exception|Interrupt)\b")


def _last_line(text: str) -> str | None:
    """The line that says why a run failed: an ``error:`` line, else the exception line of a
    traceback (with its continuation lines), else the last line."""
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    if not lines:
        return None
    for i in range(len(lines) - 1, -1, -1):
        if lines[i].startswith("error: "):
            return lines[i]
        if _EXCEPTION.match(lines[i]):
            return " ".join(lines[i:])
    return lines[-1]


def cli_args(path, method: str, output, sets: dict | None = None, seed: int = 0) -> list[str]:
    """The arguments of ``photonmap render``."""
    args = ["render", str(path), "--method", method, "-o", str(output), "--seed", str(seed)]
    for k, v in (sets or {}).items():
        args += ["--set", f"{k}={v}"]
    return args


def render_cli(
    path, method: str, sets: dict | None = None, seed: int = 0, timeout: float = 600, nice: int = 0
) -> Run:
    """Run the CLI of this checkout (``PYTHONPATH=src``) in a subprocess: what users run, and a
    crash (a segfault) is reported instead of ending the caller. The time includes the start of
    Python and the import of Mitsuba."""
    import mitsuba as mi

    write_assets()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.exr"
        code = "import sys; from photonmap.cli import app; sys.argv[0] = 'photonmap'; app()"
        cmd = [sys.executable, "-c", code, *cli_args(path, method, out, sets, seed)]
        if nice:
            cmd = ["nice", "-n", str(nice), *cmd]
        # plain tracebacks (typer's rich ones wrap the exception line at the terminal width)
        env = {**os.environ, "PYTHONPATH": str(REPO / "src"), "_TYPER_STANDARD_TRACEBACK": "1"}
        start = time.perf_counter()
        try:
            proc = subprocess.run(
                cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=timeout
            )
        except subprocess.TimeoutExpired as exc:
            err = exc.stderr.decode(errors="replace") if isinstance(exc.stderr, bytes) else ""
            return Run(-1, time.perf_counter() - start, None, f"timeout after {timeout:.0f} s", err)
        seconds = time.perf_counter() - start
        warns = [
            ln[len("warning: ") :] for ln in proc.stderr.splitlines() if ln.startswith("warning: ")
        ]
        if proc.returncode != 0 or not out.exists():
            error = _last_line(proc.stderr) or f"exit status {proc.returncode}, no output"
            if proc.returncode < 0:
                error = f"killed by signal {-proc.returncode}; last line: {error}"
            return Run(proc.returncode, seconds, None, error, proc.stderr, warns)
        image = np.array(mi.Bitmap(str(out)), dtype=np.float64)[..., :3]
        return Run(0, seconds, image, None, proc.stderr, warns)


def render_inprocess(path, method: str, sets: dict | None = None, seed: int = 0) -> Run:
    """The same command through ``photonmap.cli.app`` in this process (no start-up cost; a
    crash ends the caller)."""
    import mitsuba as mi
    from typer.testing import CliRunner

    from photonmap.cli import app

    write_assets()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.exr"
        start = time.perf_counter()
        result = CliRunner().invoke(app, cli_args(path, method, out, sets, seed))
        seconds = time.perf_counter() - start
        stderr = result.stderr
        warns = [ln[len("warning: ") :] for ln in stderr.splitlines() if ln.startswith("warning: ")]
        if result.exit_code != 0 or not out.exists():
            error = _last_line(stderr)
            if result.exception is not None and not isinstance(result.exception, SystemExit):
                exc = result.exception
                error = f"{type(exc).__name__}: {exc}".splitlines()[0]
            return Run(result.exit_code, seconds, None, error, stderr, warns)
        image = np.array(mi.Bitmap(str(out)), dtype=np.float64)[..., :3]
        return Run(0, seconds, image, None, stderr, warns)


def errors(image, ref) -> dict:
    """``photonmap.compare`` of a method's image against the reference: ``brightness`` (ratio of
    the means), ``block_rel_rmse`` (RMSE of 4 × 4-block means over the reference's mean), ..."""
    from photonmap import compare

    if image.shape != ref.shape:
        return {"shape": list(image.shape[:2]), "ref_shape": list(ref.shape[:2])}
    if not np.all(np.isfinite(image)):
        return {"nonfinite": int(np.sum(~np.isfinite(image)))}
    return compare(image, ref)


# -------------------------------------------------------------------------------- calibration
def _block_noise(images: list[np.ndarray], ref: np.ndarray) -> float:
    """Per-image 4 × 4-block noise over a set of renders with different seeds, relative to the
    reference's mean: the RMS block deviation from their mean, unbiased for the sample count."""
    from photonmap.core.image import block_means

    blocks = np.stack([block_means(im) for im in images])
    dev = blocks - blocks.mean(axis=0)
    n = len(images)
    return float(np.sqrt(np.mean(dev**2) * n / (n - 1)) / np.mean(np.abs(ref)))


def reference_noise(path, ref: np.ndarray, ref_spp: int, spp: int = 512) -> float:
    """The 4 × 4-block noise of a ``ref_spp``-sample reference: an independent ``spp``-sample
    Mitsuba render against it, scaled by √(spp / ref_spp) (its own share taken out)."""
    import mitsuba as mi

    scene = load(path)
    integrator = scene.integrator() or mi.load_dict({"type": "path"})
    image = mitsuba_reference.render(scene, integrator=integrator, spp=spp, seed=20_000)[..., :3]
    e = errors(np.asarray(image, np.float64), ref)["block_rel_rmse"]
    ratio = spp / ref_spp
    return float(e * np.sqrt(ratio / (1 + ratio)))


def _round_up(x: float) -> float:
    """Two significant digits, rounded up."""
    if x <= 0:
        return 0.01
    e = 10 ** (np.floor(np.log10(x)) - 1)
    return float(np.ceil(x / e - 1e-9) * e)


def calibrate(
    names=None, methods=METHODS, seeds=(0, 1, 2), ref_spp: int = TEST_REF_SPP, progress=print
) -> dict:
    """Each (file, method) at the test settings over ``seeds``, against the test reference:
    status, per-seed brightness and block error, the block error of the seeds' mean image (the
    bias, mostly), the per-image block noise, the reference's own block noise, and the bound
    the tests state: twice the larger of the worst seed's error and the error an unbiased
    method would reach, √(noise² + reference noise²), rounded up to two digits."""
    files = [scene_path(n) for n in names] if names else scene_files()
    out = {}
    for path in files:
        ref, info = reference(path, ref_spp)
        ref_noise = reference_noise(path, ref, info["spp"])
        for method in methods:
            sets = test_sets(path.stem, method)
            runs = [render_inprocess(path, method, sets, seed=s) for s in seeds]
            row = {
                "file": path.stem,
                "method": method,
                "sets": sets,
                "seeds": list(seeds),
                "ref_spp": info["spp"],
                "ref_noise": ref_noise,
                "seconds": [r.seconds for r in runs],
                "returncode": [r.returncode for r in runs],
            }
            if any(r.image is None for r in runs):
                row["error"] = next(r.error for r in runs if r.image is None)
                row["refused"] = all(r.refused for r in runs)
            else:
                errs = [errors(r.image, ref) for r in runs]
                mean = errors(np.mean([r.image for r in runs], axis=0), ref)
                noise = _block_noise([r.image for r in runs], ref)
                unbiased = float(np.hypot(noise, ref_noise))
                worst = max(e["block_rel_rmse"] for e in errs)
                row.update(
                    brightness=[e["brightness"] for e in errs],
                    block=[e["block_rel_rmse"] for e in errs],
                    mean_brightness=mean["brightness"],
                    mean_block=mean["block_rel_rmse"],
                    noise=noise,
                    unbiased=unbiased,
                    bound=_round_up(2 * max(worst, unbiased)),
                    bound_unbiased=_round_up(2 * unbiased),
                )
            out[f"{path.stem}/{method}"] = row
            if progress:
                progress(_calibration_line(row))
    return out


def _calibration_line(row: dict) -> str:
    head = f"{row['file']:26s} {row['method']:8s} {max(row['seconds']):5.1f} s"
    if "error" in row:
        return f"{head}  {'refused' if row['refused'] else 'FAILED'}: {row['error']}"
    b = ", ".join(f"{x:.3f}" for x in row["brightness"])
    e = ", ".join(f"{x:.3f}" for x in row["block"])
    return (
        f"{head}  brightness {b}  block {e}  mean-image block {row['mean_block']:.3f}  "
        f"noise {row['noise']:.3f}  ref noise {row['ref_noise']:.3f}  bound {row['bound']}"
        f" (unbiased {row['bound_unbiased']})"
    )


def main(argv: list[str]) -> None:
    if argv[:1] == ["assets"]:
        for p in write_assets():
            print(p)
    elif argv[:1] == ["reference"] and len(argv) in (2, 3):
        spp = int(argv[2]) if len(argv) == 3 else 4096
        image, info = reference(Path(argv[1]), spp)
        print(info, "mean", image.mean())
    elif argv[:1] == ["calibrate"]:
        import json

        names = argv[1].split(",") if len(argv) > 1 and argv[1] != "all" else None
        methods = argv[2].split(",") if len(argv) > 2 else METHODS
        result = calibrate(names, methods)
        target = REPO / "benchmarks" / "results" / "user_scenes_calibration.json"
        if target.exists():  # a partial run updates its cases
            result = {**json.loads(target.read_text()), **result}
        target.write_text(json.dumps(result, indent=1) + "\n")
        print(f"wrote {target}")
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main(sys.argv[1:])
