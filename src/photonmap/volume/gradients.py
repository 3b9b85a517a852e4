"""A small differentiable re-statement of the volume method (Sun et al. 2008 §4.4–4.5).

The fast pipeline (:mod:`.march`, :mod:`.view`) steps photons through an octree, deposits them
with an exact integer line rasterizer into a 64-bit fixed-point grid: fast, exact and not
differentiable. :class:`DifferentiableVolumeCaustic` restates the same transport with every
discrete choice replaced by a smooth one, so that Dr.Jit's AD (reverse and forward mode) gives
the derivatives of an image of the volume caustic with respect to the fog's σ_s, σ_a (κ = σ_s +
σ_a) and the refractive-index grid n. Everything is in voxel units (voxel edge h = 1; the grid
box is ``[0, R]³``, voxel ``(i, j, k)`` has its centre at ``(i+½, j+½, k+½)``; tensors are
indexed ``[z, y, x]`` like the rest of the project).

**Fields.** n, σ_s, σ_a are read by trilinear interpolation between voxel centres with
clamp-to-edge addressing (spec §0.2), which is linear in the grid values and continuous in the
position. ∇n is Sun's S3: central differences of the n grid (one-sided at the faces, as
``numpy.gradient``), itself interpolated trilinearly, so ∇n is linear in n too.

**Photon march** (Sun §4.4 eqs 4–6) with a *fixed* step Δs and a fixed number of steps,
unrolled in Python (one vectorized Dr.Jit operation per step over all photons; reverse-mode AD
through Dr.Jit's symbolic loops is not available)::

    x_{i+1} = x_i + (Δs / n(x_i)) · v_i                         (4)
    v_{i+1} = v_i + Δs · ∇n(x_i)                                (5)
    L̃_{i+1} = L̃_i · exp(−κ(x_i) · ‖x_{i+1} − x_i‖)                (6)

with ``v_0 = n(x_0) · d_0``. A photon of the parallel beam :class:`ParallelBeam` starts with
power ``L̃_0 = E · A / P`` (irradiance E over the aperture area A, P photons).

**Deposit** (the volume caustic, S7): each step adds its track length, weighted by the mean of
the energies at its ends, at the step's midpoint m_i = (x_i + x_{i+1})/2 with trilinear weights
w_c(m_i) to the 8 surrounding voxel centres (a *splat*, differentiable in the position)::

    φ[c] += w_c(m_i) · ½ (L̃_i + L̃_{i+1}) · ‖x_{i+1} − x_i‖           (track-length fluence)

Corners outside the grid receive nothing (and read back zero), so the splat and the view pass'
lookup of φ are transposes of each other, and a photon fades out continuously as it leaves.

**View pass** (Sun §4.5): an orthographic camera (:class:`OrthoCamera`) looking along −z
marches each pixel's ray from the face z = R with the fixed step Δt, bent by eqs 4–5 like the
photons (``curved_view=True``, as Sun does) or straight, and sums single scattering with an
isotropic phase function (midpoint rule per step)::

    L = Σ_j T_j · exp(−κ(m_j) Δl_j / 2) · σ_s(m_j) / (4π) · φ(m_j) · Δl_j,
    T_{j+1} = T_j · exp(−κ(m_j) Δl_j),  T_0 = 1,  Δl_j = ‖x_{j+1} − x_j‖

— the discretised ``L = ∫ T(s) σ_s(x(s)) p φ(x(s)) ds`` with ``T(s) = exp(−∫₀^s κ)``, p = 1/(4π).
Sun stores a mean photon direction per voxel for a Schlick phase; with the isotropic phase it
is not needed and not kept.

**What is differentiated:** σ_s and σ_a (scalars or grids) through eq 6, T and the view pass'
σ_s; the n grid through eqs 4–5 (the curved photon and camera paths), hence through the splat's
weights and the lookups along the camera rays. **What is not:** the octree's adaptive steps
(Δs here is fixed), adaptive emission, the fixed-point rasterizer and S8's smoothing. Derivatives
of trilinear interpolation jump where a path crosses a plane of voxel centres (the field is C⁰),
so a finite difference that moves a sample across one sees the mean of two one-sided slopes.

**Determinism.** The photons and rays are fixed (or jittered from a seed), so the same inputs
give the same image and derivatives up to the order of Dr.Jit's floating-point scatter-adds (the
splat, and the reverse mode of every gather), which run in thread order on the LLVM backend:
relative differences of about 10⁻⁷ in float32 and 10⁻¹⁵ in float64. (Evaluating with one thread
would make them bit-identical, but ``dr.set_thread_count`` after Dr.Jit's kernel history was
switched on and off gave wrong gradients in Dr.Jit 1.5, so the thread count is left alone.)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.arrays import to_jit
from ..core.checkpoint import Checkpoint
from ..core.errors import ParameterError

INV_FOUR_PI = 1.0 / (4.0 * math.pi)
PARAMETERS = ("n", "sigma_s", "sigma_a")
CHECKPOINT = True  # wrap each step in a Checkpoint (False: one AD graph; slow, for tests)


@dataclass(frozen=True)
class ParallelBeam:
    """``side × side`` photons on a square aperture of edge ``width`` (voxels) centred at
    ``center``, all travelling along ``direction``; ``irradiance`` E is the power per unit area
    across the beam. Photons sit at the cell centres of the aperture (deterministic), or jittered
    inside their cells by a NumPy generator seeded with ``seed``."""

    center: tuple = (8.0, 16.0, 8.0)
    direction: tuple = (0.0, -1.0, 0.0)
    width: float = 8.0
    side: int = 32
    irradiance: float = 1.0
    seed: int | None = None

    def photons(self):
        """Origins (P, 3), unit directions (P, 3) and the power of one photon, as NumPy."""
        d = np.asarray(self.direction, np.float64)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
            raise ParameterError(f"beam direction must be a finite non-zero 3-vector, got {d}")
        if self.side < 1 or not (self.width > 0 and math.isfinite(self.width)):
            raise ParameterError(
                f"beam needs side ≥ 1 and a finite width > 0, got side={self.side}, "
                f"width={self.width}"
            )
        if not (self.irradiance >= 0 and math.isfinite(self.irradiance)):
            raise ParameterError(f"beam irradiance must be finite and ≥ 0, got {self.irradiance}")
        d = d / np.linalg.norm(d)
        a = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
        e1 = np.cross(d, a)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(d, e1)
        s = self.side
        jj, ii = np.meshgrid(np.arange(s), np.arange(s), indexing="ij")
        u = np.stack([ii.ravel(), jj.ravel()], 1) + 0.5
        if self.seed is not None:
            u += np.random.default_rng(self.seed).uniform(-0.5, 0.5, u.shape)
        u = (u / s - 0.5) * self.width
        origins = np.asarray(self.center, np.float64) + u[:, :1] * e1 + u[:, 1:] * e2
        power = self.irradiance * self.width**2 / s**2
        return origins, np.broadcast_to(d, origins.shape), power


@dataclass(frozen=True)
class OrthoCamera:
    """An orthographic camera looking along −z at the grid's face z = R: ``width × height``
    pixels over the window ``[x0, x1] × [y0, y1]`` (voxels; ``None``: the whole face), row 0 at
    the top (largest y)."""

    width: int = 32
    height: int = 32
    window: tuple | None = None

    def rays(self, resolution: int):
        if self.width < 1 or self.height < 1:
            raise ParameterError(f"camera needs ≥ 1 pixel, got {self.width}×{self.height}")
        x0, x1, y0, y1 = self.window or (0.0, resolution, 0.0, resolution)
        jj, ii = np.meshgrid(np.arange(self.height), np.arange(self.width), indexing="ij")
        x = x0 + (ii.ravel() + 0.5) / self.width * (x1 - x0)
        y = y1 - (jj.ravel() + 0.5) / self.height * (y1 - y0)
        origins = np.stack([x, y, np.full_like(x, float(resolution))], 1)
        return origins, np.broadcast_to(np.array([0.0, 0.0, -1.0]), origins.shape)


class DifferentiableVolumeCaustic:
    """Differentiable volume caustic of a refractive-index grid in fog (module docstring).

    ``resolution`` R: the grid is R³ voxels. ``photon_steps`` steps of ``ds`` (voxels) per photon
    (default: enough to cross the grid diagonal once); ``view_steps`` steps of ``dt`` per camera
    ray (default: the depth R). ``double``: compute in float64 (inputs are cast; the cast is
    differentiable). Call :meth:`render` with Dr.Jit AD, or :meth:`value_and_grad` /
    :meth:`forward_grad` for the derivatives as NumPy values."""

    def __init__(
        self,
        resolution: int,
        light: ParallelBeam | None = None,
        camera: OrthoCamera | None = None,
        *,
        ds: float = 0.5,
        photon_steps: int | None = None,
        dt: float = 0.5,
        view_steps: int | None = None,
        curved_view: bool = True,
        double: bool = False,
    ):
        r = int(resolution)
        if r != resolution or not 2 <= r <= 256:
            raise ParameterError(f"resolution must be an integer in [2, 256], got {resolution!r}")
        for name, value in (("ds", ds), ("dt", dt)):
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ParameterError(f"{name} must be a finite step > 0 voxels, got {value!r}")
        self.R = r
        self.light = light or ParallelBeam(center=(r / 2, float(r), r / 2), width=r / 2)
        self.camera = camera or OrthoCamera()
        self.ds, self.dt = float(ds), float(dt)
        self.photon_steps = photon_steps or math.ceil(math.sqrt(3) * r / self.ds)
        self.view_steps = view_steps or math.ceil(r / self.dt)
        for name, value in (("photon_steps", self.photon_steps), ("view_steps", self.view_steps)):
            if int(value) != value or value < 1:
                raise ParameterError(f"{name} must be an integer ≥ 1, got {value!r}")
        self.curved_view = bool(curved_view)
        self.Float = mi.Float64 if double else mi.Float
        self.Tensor = mi.TensorXf64 if double else mi.TensorXf
        self._photons = self.light.photons()
        self._rays = self.camera.rays(r)

    # ---- inputs ---------------------------------------------------------------------------
    def _grid(self, name: str, value, *, scalar_ok: bool, positive: bool):
        """``value`` as ('scalar', Float of width 1) or ('grid', flat Float of R³), checked."""
        r = self.R
        if isinstance(value, int | float) and not isinstance(value, bool):
            if not scalar_ok:
                raise ParameterError(f"{name} must be a grid of shape ({r}, {r}, {r})")
            value = dr.opaque(self.Float, value)  # a literal would make a kernel per value
        if dr.is_tensor_v(value):
            shape = tuple(value.shape)
            if shape != (r, r, r):
                raise ParameterError(
                    f"{name} has shape {shape}; it must be ({r}, {r}, {r}) (the grid) "
                    + ("or a scalar" if scalar_ok else "")
                )
            kind, flat = "grid", self.Float(value.array)
        elif isinstance(value, np.ndarray):
            if value.shape != (r, r, r):
                raise ParameterError(f"{name} has shape {value.shape}; it must be ({r}, {r}, {r})")
            kind, flat = "grid", to_jit(self.Float, np.asarray(value, np.float64).ravel())
        elif dr.is_array_v(value) and dr.depth_v(value) == 1 and dr.width(value) == 1:
            if not scalar_ok:
                raise ParameterError(f"{name} must be a grid of shape ({r}, {r}, {r})")
            kind, flat = "scalar", self.Float(value)
        else:
            raise ParameterError(
                f"{name} must be a ({r}, {r}, {r}) tensor or array"
                + (" or a scalar" if scalar_ok else "")
                + f", got {type(value).__name__}"
            )
        values = np.asarray(dr.detach(flat), np.float64)
        if not np.all(np.isfinite(values)):
            raise ParameterError(f"{name} holds NaN or infinite values")
        low = values.min()
        if positive and low <= 0:
            raise ParameterError(f"{name} must be > 0 everywhere; its minimum is {low:g}")
        if not positive and low < 0:
            raise ParameterError(f"{name} must be ≥ 0 everywhere; its minimum is {low:g}")
        return kind, flat

    # ---- interpolation ----------------------------------------------------------------------
    def _corners(self, p):
        """The 8 trilinear corners of voxel position ``p`` (tuple of 3 Floats): (flat index
        clamped into the grid, weight, inside-the-grid mask) each. Positions are first clamped
        to [−1, R+1] so that far-away or NaN-free huge coordinates index safely."""
        r = self.R
        u = [dr.clip(c, -1.0, r + 1.0) - 0.5 for c in p]
        i0 = [dr.floor(c) for c in u]
        f = [c - i for c, i in zip(u, i0, strict=True)]
        i0 = [mi.Int32(i) for i in i0]
        out = []
        for dz in (0, 1):
            for dy in (0, 1):
                for dx in (0, 1):
                    w = (
                        (f[0] if dx else 1.0 - f[0])
                        * (f[1] if dy else 1.0 - f[1])
                        * (f[2] if dz else 1.0 - f[2])
                    )
                    ix, iy, iz = i0[0] + dx, i0[1] + dy, i0[2] + dz
                    inside = (ix >= 0) & (ix < r) & (iy >= 0) & (iy < r) & (iz >= 0) & (iz < r)
                    ix, iy, iz = (dr.clip(i, 0, r - 1) for i in (ix, iy, iz))
                    out.append((mi.UInt32((iz * r + iy) * r + ix), w, inside))
        return out

    def _sample(self, corners, fields, zero_outside=False):
        """Trilinear values of flat grids ``fields`` at the corners' position."""
        acc = [None] * len(fields)
        for idx, w, inside in corners:
            if zero_outside:
                w = dr.select(inside, w, 0.0)
            for k, field in enumerate(fields):
                term = w * dr.gather(self.Float, field, idx)
                acc[k] = term if acc[k] is None else acc[k] + term
        return acc

    def _field(self, corners, field):
        kind, flat = field
        return flat if kind == "scalar" else self._sample(corners, [flat])[0]

    def _gradient(self, n):
        """Central differences of the flat n grid (one-sided at the faces): ∂n/∂x, ∂n/∂y, ∂n/∂z
        per voxel, linear in n (Sun's S3 without the blur)."""
        r = self.R
        i = dr.arange(mi.UInt32, r**3)
        coords = (i % r, (i // r) % r, i // (r * r))
        strides = (1, r, r * r)
        grads = []
        for c, stride in zip(coords, strides, strict=True):
            lo = dr.select(c > 0, i - stride, i)
            hi = dr.select(c < r - 1, i + stride, i)
            span = self.Float(dr.select(c > 0, 1, 0) + dr.select(c < r - 1, 1, 0))
            grads.append((dr.gather(self.Float, n, hi) - dr.gather(self.Float, n, lo)) / span)
        return grads

    # ---- transport ----------------------------------------------------------------------------
    def _step(self, x, v, n_grids, h):
        """Eqs 4–5 with step ``h``: (x', v', corners of x)."""
        corners = self._corners(x)
        nn, gx, gy, gz = self._sample(corners, n_grids)
        x1 = tuple(xc + (h / nn) * vc for xc, vc in zip(x, v, strict=True))
        v1 = (v[0] + h * gx, v[1] + h * gy, v[2] + h * gz)
        return x1, v1, corners

    @staticmethod
    def _length(a, b):
        return dr.sqrt(dr.square(b[0] - a[0]) + dr.square(b[1] - a[1]) + dr.square(b[2] - a[2]))

    def _start(self, origins, directions, n_grids):
        x = tuple(to_jit(self.Float, origins[:, k]) for k in range(3))
        n0 = self._sample(self._corners(x), n_grids[:1])[0]
        v = tuple(n0 * to_jit(self.Float, directions[:, k]) for k in range(3))
        return x, v

    def _inputs(self, n, sigma_s, sigma_a):
        n = self._grid("n", n, scalar_ok=False, positive=True)[1]
        sigma_s = self._grid("sigma_s", sigma_s, scalar_ok=True, positive=False)
        sigma_a = self._grid("sigma_a", sigma_a, scalar_ok=True, positive=False)
        kind = "grid" if "grid" in (sigma_s[0], sigma_a[0]) else "scalar"
        kappa = (kind, sigma_s[1] + sigma_a[1])  # a scalar broadcasts over the grid
        return (n, *self._gradient(n)), sigma_s, kappa

    def _photon_step(self, state, params):
        """One photon step (eqs 4–6) and its splat into the fluence grid."""
        x, v, energy, fluence = state
        n_grids, kappa = params
        x1, v1, corners = self._step(x, v, n_grids, self.ds)
        dl = self._length(x, x1)
        e1 = energy * dr.exp(-self._field(corners, kappa) * dl)
        mid = tuple(0.5 * (a + b) for a, b in zip(x, x1, strict=True))
        value = 0.5 * (energy + e1) * dl
        deposit = dr.zeros(self.Float, self.R**3)
        for idx, w, inside in self._corners(mid):
            dr.scatter_add(deposit, w * value, idx, active=inside)
        return x1, v1, e1, fluence + deposit

    def _view_step(self, state, params):
        """One camera-ray step: eqs 4–5 (or a straight step) and the midpoint single-scattering
        term of the view pass."""
        x, v, transmittance, radiance = state
        n_grids, fluence, sigma_s, kappa = params
        if self.curved_view:
            x1, v1, _ = self._step(x, v, n_grids, self.dt)
        else:
            x1, v1 = tuple(a + self.dt * b for a, b in zip(x, v, strict=True)), v
        dl = self._length(x, x1)
        mid = tuple(0.5 * (a + b) for a, b in zip(x, x1, strict=True))
        corners = self._corners(mid)
        phi = self._sample(corners, [fluence], zero_outside=True)[0]
        tau = self._field(corners, kappa) * dl
        scatter = self._field(corners, sigma_s) * INV_FOUR_PI
        radiance = radiance + transmittance * dr.exp(-0.5 * tau) * scatter * phi * dl
        return x1, v1, transmittance * dr.exp(-tau), radiance

    def _scan(self, fn, state, params, steps, record=None):
        """``steps`` applications of ``fn(state, params) → state``, each one evaluated and, when
        anything is differentiated, wrapped in a :class:`~photonmap.core.checkpoint.Checkpoint`
        so that AD replays one step at a time (small kernels, the same for every step) instead of
        one huge graph."""
        for _ in range(steps):
            if CHECKPOINT and dr.grad_enabled(state, params):
                state = dr.custom(Checkpoint, fn, state, params)
            else:
                state = fn(state, params)
                dr.eval(state)
            if record is not None:
                record.append(state[0])
        return state

    def trace(self, n, sigma_a=0.0, sigma_s=0.0, record=False):
        """March the photons (eqs 4–6) through ``n`` with extinction κ = σ_s + σ_a and return
        ``(fluence, x, v, L̃)``: the flat fluence grid φ (R³, the volume caustic) and the final
        photon state; ``record=True`` adds the list of positions before and after every step."""
        n_grids, _, kappa = self._inputs(n, sigma_s, sigma_a)
        out = self._trace(n_grids, kappa, record)
        dr.eval(out[:4])
        return out

    def _trace(self, n_grids, kappa, record=False):
        origins, directions, power = self._photons
        x, v = self._start(origins, directions, n_grids)
        energy = dr.full(self.Float, power, len(origins))
        state = (x, v, energy, dr.zeros(self.Float, self.R**3))
        path = [x] if record else None
        x, v, energy, fluence = self._scan(
            self._photon_step, state, (n_grids, kappa), self.photon_steps, path
        )
        return (fluence, x, v, energy, path) if record else (fluence, x, v, energy)

    def _view(self, fluence, n_grids, sigma_s, kappa):
        origins, directions = self._rays
        if self.curved_view:
            x, v = self._start(origins, directions, n_grids)
        else:
            x = tuple(to_jit(self.Float, origins[:, k]) for k in range(3))
            v = tuple(to_jit(self.Float, directions[:, k]) for k in range(3))
        count = len(origins)
        state = (x, v, dr.full(self.Float, 1.0, count), dr.zeros(self.Float, count))
        params = (n_grids, fluence, sigma_s, kappa)
        return self._scan(self._view_step, state, params, self.view_steps)[3]

    def render(self, n, sigma_s, sigma_a=0.0):
        """The image (a ``(height, width)`` tensor) of the volume caustic: photons through n,
        splatted into φ, gathered by the camera. Attached to whatever inputs have gradients
        enabled (Dr.Jit AD, reverse or forward)."""
        n_grids, sigma_s, kappa = self._inputs(n, sigma_s, sigma_a)
        fluence = self._trace(n_grids, kappa)[0]
        image = self._view(fluence, n_grids, sigma_s, kappa)
        dr.eval(image)
        return self.Tensor(image, shape=(self.camera.height, self.camera.width))

    def roughness(self, n):
        """Σ over voxels of |∇n|² (the central differences that eq 5 reads): a smoothness
        penalty for fitting n, differentiable like :meth:`render`."""
        flat = self._grid("n", n, scalar_ok=False, positive=True)[1]
        return sum(dr.sum(dr.square(g)) for g in self._gradient(flat))

    # ---- derivatives as NumPy values -----------------------------------------------------------
    def _prepared(self, params: Mapping):
        unknown = set(params) - set(PARAMETERS)
        if unknown:
            raise ParameterError(f"unknown parameters {sorted(unknown)}; use {PARAMETERS}")
        if "n" not in params or "sigma_s" not in params:
            raise ParameterError("params needs at least 'n' and 'sigma_s'")
        out = {}
        for name, value in params.items():
            kind, flat = self._grid(name, value, scalar_ok=name != "n", positive=name == "n")
            flat = self.Float(dr.detach(flat))  # a fresh leaf: gradients land here
            out[name] = self.Tensor(flat, shape=(self.R,) * 3) if kind == "grid" else flat
        return out

    def value_and_grad(self, loss: Callable, params: Mapping, wrt=PARAMETERS):
        """``loss(image)`` → Dr.Jit scalar; returns ``(value, {name: gradient as NumPy})`` for
        the names in ``wrt`` by reverse-mode AD.
        ``params``: ``n`` and ``sigma_s``, optionally ``sigma_a``; scalars or grids."""
        params = self._prepared(params)
        for name in wrt:
            if name in params:
                dr.enable_grad(params[name])
        value = loss(self.render(**params))
        dr.backward(value)
        grads = {name: np.array(dr.grad(params[name]), np.float64) for name in wrt if name in params}
        return float(value.array[0] if dr.is_tensor_v(value) else value[0]), grads

    def forward_grad(self, loss: Callable, params: Mapping, tangents: Mapping):
        """Directional derivative of ``loss(image)`` along ``tangents`` ({name: array of the
        parameter's shape}) by forward-mode AD."""
        params = self._prepared(params)
        for name, t in tangents.items():
            if name not in params:
                raise ParameterError(f"tangent for {name!r}, which is not in params")
            p = params[name]
            dr.enable_grad(p)
            tangent = np.asarray(t, np.float64)
            shape = tuple(p.shape) if dr.is_tensor_v(p) else ()
            if tangent.shape != shape or not np.all(np.isfinite(tangent)):
                raise ParameterError(
                    f"tangent for {name!r} must be finite with shape {shape}, "
                    f"got shape {tangent.shape}"
                )
            grad = to_jit(self.Float, tangent.ravel()) if shape else dr.opaque(self.Float, float(tangent))
            dr.set_grad(p, self.Tensor(grad, shape=shape) if shape else grad)
        value = loss(self.render(**params))
        dr.forward_to(value)
        grad = dr.grad(value)
        return float((grad.array if dr.is_tensor_v(grad) else grad)[0])
