"""The MIS weights of vertex connection and merging sum to one over the techniques of a path
(Georgiev et al. 2012, Eq. 10; Georgiev 2012, TR (37)–(47)).

Random paths ``z_0`` (on a light) … ``z_k`` (the camera) of random vertices, normals and
non-symmetric BSDF densities (``p(ω_i → ω_o) ≠ p(ω_o → ω_i)``), a camera importance and a
next-event density of the light point that differs from the emission's. The weights are computed
as the renderer computes them — :mod:`photonmap.vcm.mis`'s recursions along each subpath and its
technique weights — and compared, technique by technique, with the balance heuristic of the
explicit path densities ``p_s = Π light-side densities × Π camera-side densities`` (merges:
``η p`` with the merged vertex sampled from both sides); the weights of all techniques sum to 1.
"""

import math

import numpy as np
import pytest

from photonmap.vcm import mis

A = 0.7  # the light's area density (emission)


def unit(v):
    return v / np.linalg.norm(v)


class RandomPath:
    """A path of ``k`` segments with random geometry and densities."""

    def __init__(self, k: int, rng):
        self.k = k
        self.z = rng.uniform(-1, 1, (k + 1, 3))
        self.n = np.array([unit(v) for v in rng.normal(size=(k + 1, 3))])
        self.forward = unit(rng.normal(size=3))  # the camera's axis
        self.skew = rng.uniform(0.1, 0.6, k + 1)  # per vertex: the BSDF's asymmetry

    def dir(self, i, j):
        """Unit direction from ``z_i`` to ``z_j``."""
        return unit(self.z[j] - self.z[i])

    def d2(self, i, j):
        return float(np.sum((self.z[j] - self.z[i]) ** 2))

    def cos(self, i, j):
        """|cos| at ``z_i`` of the direction to ``z_j``."""
        return abs(float(self.n[i] @ self.dir(i, j)))

    def bsdf_pdf(self, i, towards_in, towards_out):
        """Density at ``z_i`` of sampling the direction to ``z_out`` when the path came from
        ``z_in`` (solid angle; not symmetric)."""
        wi = self.dir(i, towards_in)
        return (1.0 + self.skew[i] * (wi @ self.n[i]) + 0.3) * self.cos(i, towards_out) / math.pi

    def importance(self):
        """The camera's density of the direction to ``z_{k-1}`` (solid angle)."""
        c = abs(float(self.forward @ self.dir(self.k, self.k - 1)))
        return 1.0 / (2.0 * c**3)

    def p_emission(self):
        """The emission density of ``z_0`` towards ``z_1`` per area and solid angle."""
        return A * self.cos(0, 1) / math.pi

    def p_nee_area(self):
        """Next-event estimation's density of ``z_0`` seen from ``z_1``, per area."""
        return A * (1.0 + 0.5 * self.cos(0, 1))

    # ---------------------------------------------------------------- explicit densities
    def light_density(self, j):
        """Density per area of ``z_j`` on the light subpath."""
        if j == 0:
            return A
        if j == 1:
            return self.cos(0, 1) / math.pi * self.cos(1, 0) / self.d2(0, 1)
        return self.bsdf_pdf(j - 1, j - 2, j) * self.cos(j, j - 1) / self.d2(j - 1, j)

    def camera_density(self, i):
        """Density per area of ``z_i`` on the camera subpath."""
        k = self.k
        if i == k - 1:
            return self.importance() * self.cos(i, k) / self.d2(i, k)
        return self.bsdf_pdf(i + 1, i + 2, i) * self.cos(i, i + 1) / self.d2(i, i + 1)

    def technique_densities(self, eta, merging: bool):
        """``{name: p}``: connection techniques ``s`` (light vertices) 0 … k and merges at
        ``z_m``, 1 ≤ m ≤ k − 1."""
        k = self.k
        L = [self.light_density(j) for j in range(k)]
        C = [self.camera_density(i) for i in range(k)]
        out = {}
        for s in range(k + 1):
            light = self.p_nee_area() if s == 1 else math.prod(L[:s])
            out[f"s={s}"] = light * math.prod(C[s:])
        if merging:
            for m in range(1, k):
                out[f"merge {m}"] = eta * math.prod(L[: m + 1]) * math.prod(C[m:])
        return out

    # ---------------------------------------------------------------- the renderer's recursions
    def light_quantities(self, vm_factor, vc_factor):
        """``(dVCM, dVC, dVM)`` of the light subpath at ``z_1 … z_{k-1}``."""
        q = {}
        p_e = self.p_emission()
        vc, vm = mis.light_start(p_e, self.cos(0, 1), vc_factor)
        vcm = mis.first_light_hit(self.p_nee_area(), p_e, self.d2(0, 1), self.cos(1, 0))
        _, vc, vm = mis.after_hit(vcm, vc, vm, self.d2(0, 1), self.cos(1, 0))
        q[1] = (vcm, vc, vm)
        for j in range(1, self.k - 1):
            vcm, vc, vm = mis.after_bounce(
                vcm, vc, vm, self.cos(j, j + 1), self.bsdf_pdf(j, j - 1, j + 1),
                self.bsdf_pdf(j, j + 1, j - 1), vm_factor, vc_factor,
            )  # fmt: skip
            vcm, vc, vm = mis.after_hit(vcm, vc, vm, self.d2(j, j + 1), self.cos(j + 1, j))
            q[j + 1] = (vcm, vc, vm)
        return q

    def camera_quantities(self, vm_factor, vc_factor, connect=True):
        """``(dVCM, dVC, dVM)`` of the camera subpath at ``z_{k-1} … z_0``."""
        k = self.k
        vcm, vc, vm = 1.0 / self.importance(), 0.0, 0.0
        vcm, vc, vm = mis.after_hit(vcm, vc, vm, self.d2(k, k - 1), self.cos(k - 1, k))
        q = {k - 1: (vcm, vc, vm)}
        for i in range(k - 1, 0, -1):
            vcm, vc, vm = mis.after_bounce(
                vcm, vc, vm, self.cos(i, i - 1), self.bsdf_pdf(i, i + 1, i - 1),
                self.bsdf_pdf(i, i - 1, i + 1), vm_factor, vc_factor,
            )  # fmt: skip
            if not connect:
                vc = 0.0
            vcm, vc, vm = mis.after_hit(vcm, vc, vm, self.d2(i, i - 1), self.cos(i - 1, i))
            q[i - 1] = (vcm, vc, vm)
        return q

    def weights(self, mode: str, eta: float) -> dict:
        """Each technique's weight as the renderer computes it in ``mode``."""
        k = self.k
        vm_factor = eta if mode == "vcm" else 0.0
        vc_factor = 1.0 / eta if mode == "vcm" else 0.0
        light = self.light_quantities(vm_factor, vc_factor)
        camera = self.camera_quantities(vm_factor, vc_factor, connect=mode != "pt")
        p_e, cos_light = self.p_emission(), self.cos(0, 1)
        out = {}
        vcm, vc, _ = camera[0]
        out["s=0"] = mis.emission_weight(vcm, vc, self.p_nee_area(), p_e)
        vcm, vc, _ = camera[1]
        p_direct = self.p_nee_area() * self.d2(0, 1) / cos_light  # per solid angle at z_1
        out["s=1"] = mis.next_event_weight(
            (vcm, vc, self.bsdf_pdf(1, 2, 0), self.bsdf_pdf(1, 0, 2), self.cos(1, 0)),
            (p_direct, 0.0 if mode == "pt" else p_e, cos_light), vm_factor,
        )  # fmt: skip
        if mode == "pt":
            return out
        for s in range(2, k):
            light_end = (*light[s - 1][:2], self.bsdf_pdf(s - 1, s - 2, s),
                         self.bsdf_pdf(s - 1, s, s - 2), self.cos(s - 1, s))  # fmt: skip
            camera_end = (*camera[s][:2], self.bsdf_pdf(s, s + 1, s - 1),
                          self.bsdf_pdf(s, s - 1, s + 1), self.cos(s, s - 1))  # fmt: skip
            d2 = self.d2(s - 1, s)
            out[f"s={s}"] = mis.connection_weight(light_end, camera_end, d2, vm_factor)
        vcm, vc, _ = light[k - 1]
        p_camera = self.importance() * self.cos(k - 1, k) / self.d2(k - 1, k)
        out[f"s={k}"] = mis.light_tracing_weight(
            vcm, vc, p_camera, self.bsdf_pdf(k - 1, k, k - 2), vm_factor
        )
        if mode == "vcm":
            for m in range(1, k):
                out[f"merge {m}"] = mis.merge_weight(
                    light[m][::2], camera[m][::2], self.bsdf_pdf(m, m + 1, m - 1),
                    self.bsdf_pdf(m, m - 1, m + 1), vc_factor,
                )  # fmt: skip
        return out


@pytest.mark.parametrize("mode", ["vcm", "bpt", "pt"])
@pytest.mark.parametrize("k", [3, 4, 5, 7])
def test_weights_are_the_balance_heuristic_and_sum_to_one(mode, k):
    rng = np.random.default_rng(k)
    for _ in range(20):
        path = RandomPath(k, rng)
        eta = float(rng.uniform(1e-3, 10.0))
        weights = path.weights(mode, eta)
        densities = path.technique_densities(eta, merging=mode == "vcm")
        if mode == "pt":
            densities = {name: densities[name] for name in ("s=0", "s=1")}
        assert set(weights) == set(densities)
        total = sum(densities.values())
        for name, w in weights.items():
            assert w == pytest.approx(densities[name] / total, rel=1e-9, abs=1e-12), name
        assert sum(weights.values()) == pytest.approx(1.0, rel=1e-9)
