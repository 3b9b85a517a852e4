"""What bounds a light-change frame of the volume method (Sun et al. 2008), for
``volume_table1.py``: each stage's share of the frame, the Dr.Jit kernels each stage launches
and compiles, and photon marching (S6/S7) timed with and without its deposition into the grids,
with the number of voxel deposits counted.
"""

from __future__ import annotations

import math

import numpy as np

from timing import median, profiling_timer, timed
from volume_frames import frame, nudge_light


def stage_shares(stages_ms: dict[str, float]) -> dict[str, float]:
    """Each stage's fraction of the summed stage times."""
    total = sum(stages_ms.values())
    return {k: v / total for k, v in stages_ms.items()} if total > 0 else {}


def profile(pipe, light_stages: dict, full_stages: dict | None, repeats: int) -> dict:
    """The profile of the headline: shares of the light-change frames' median ``light_stages``
    (and of a full render's ``full_stages``), kernels per stage, and the marching profile."""
    shares = stage_shares(light_stages)
    out = {
        "light_change_stage_ms": light_stages,
        "light_change_stage_share": shares,
        "slowest_stage": max(shares, key=shares.get) if shares else None,
        "kernels": profile_frame(pipe),
        "march": profile_march(pipe, repeats=repeats),
    }
    if full_stages is not None:
        out["full_render_stage_share"] = stage_shares(full_stages)
    return out


def profile_frame(pipe) -> dict:
    """Dr.Jit kernels launched per stage during one light-change frame (kernel history on)."""
    from photonmap.core.timer import StageTimer

    saved = pipe.timer
    pipe.timer = profiling_timer(StageTimer)()
    try:
        # a light position not used before, as in a real light move
        f = frame(pipe, nudge_light(pipe, pipe.world.lights[0], 0, step=0.5))
        stages = {}
        for stage, kernels in pipe.timer.kernels.items():
            jit = [k for k in kernels if k.get("type") == "JIT"]
            compiled = [k for k in jit if k.get("compiled")]
            stages[stage] = {
                "stage_ms": f["stages_ms"].get(stage),
                "launches": len(kernels),
                "jit_kernels": len(jit),
                "kernel_ms": sum(k.get("execution_time_ms", 0.0) for k in kernels),
                "compiled": len(compiled),
                "compile_ms": sum(k.get("backend_time_ms", 0.0) for k in compiled),
                "top_kernel": max(jit, key=lambda k: k.get("execution_time_ms", 0.0), default=None),
            }
        return {"frame_wall_ms": f["wall_ms"], "stages": stages}
    finally:
        pipe.timer = saved


class _CountingDr:
    """Forwards to ``drjit``, but every ``scatter_reduce`` traced while ``armed`` also adds 1 per
    active lane to its own slot of ``counter`` (used to count the deposits of the marching
    kernel). Dr.Jit may trace a loop body more than once and keeps only the last trace, so the
    slots of discarded traces stay 0; every executed slot of the rasteriser counts each deposit
    once."""

    SLOTS = 64

    def __init__(self, dr, uint64, uint32):
        self._dr, self._uint32 = dr, uint32
        self.counter = dr.zeros(uint64, self.SLOTS)
        self.armed, self.calls = False, 0

    def __getattr__(self, name):
        return getattr(self._dr, name)

    def scatter_reduce(self, *args, **kwargs):
        if self.armed:
            active = kwargs.get("active", args[4] if len(args) > 4 else True)
            index = kwargs.get("index", args[3] if len(args) > 3 else None)
            width = self._dr.width(index)
            slot = min(self.calls, self.SLOTS - 1)
            self.calls += 1
            self._dr.scatter_reduce(
                self._dr.ReduceOp.Add,
                self.counter,
                self._dr.full(type(self.counter), 1, width),
                self._dr.full(self._uint32, slot, width),
                active=active,
                mode=self._dr.ReduceMode.Local,
            )
        return self._dr.scatter_reduce(*args, **kwargs)


def profile_march(pipe, repeats: int = 1) -> dict:
    """Photon marching (S6/S7) on the cached photons of ``pipe``: as is, without deposition (the
    S7 rasteriser replaced by a no-op) and with a deposit counter. Depends on the internals of
    ``photonmap.volume.march`` and ``.step``; any failure is reported instead of raised."""
    from photonmap.volume import march, step

    out: dict = {}
    try:
        photons = pipe.stage_output("photon generation")
        grids = pipe.stage_output("march grids")
        p, h = pipe.params, pipe.world.box.h

        def run():
            return march.march(photons, grids, march.Marching(p.ds_min, fidelity=p.fidelity), h)

        def time_march():
            run()  # warm-up (compiles this variant)
            times = [timed(run) for _ in range(repeats)]
            return median(t for t, _ in times), times[-1][1]

        full_s, result = time_march()
        out["with_deposits_s"] = full_s
        out["steps"] = int(result.steps)
        original = step.deposit_segment
        step.deposit_segment = lambda *args, **kwargs: None
        try:
            bare_s, bare = time_march()
        finally:
            step.deposit_segment = original
        out["without_deposits_s"] = bare_s
        out["without_deposits_steps"] = int(bare.steps)
        out["deposition_share"] = max(0.0, 1.0 - bare_s / full_s) if full_s > 0 else math.nan
        out["msteps_per_s_with_deposits"] = result.steps / 1e6 / full_s
        out["msteps_per_s_without_deposits"] = bare.steps / 1e6 / bare_s
    except Exception as exc:  # noqa: BLE001 - a profile must never break the benchmark
        out["error"] = f"{type(exc).__name__}: {exc}"
        return out
    try:
        out.update(count_deposits(step, run, out))
    except Exception as exc:  # noqa: BLE001
        out["deposits_error"] = f"{type(exc).__name__}: {exc}"
    return out


def count_deposits(step, run, timed_march: dict) -> dict:
    """The lanes reaching the rasteriser's scatters during one more ``run()`` of the march
    (``step`` is the module that calls ``deposit_segment``)."""
    import drjit as dr
    import mitsuba as mi

    proxy = _CountingDr(dr, dr.uint64_array_t(mi.Float), mi.UInt32)
    original, real_dr = step.deposit_segment, step.dr

    def counting(*args, **kwargs):
        proxy.armed = True
        try:
            return original(*args, **kwargs)
        finally:
            proxy.armed = False

    if getattr(original, "__globals__", None) is not vars(step):
        raise RuntimeError("deposit_segment does not read drjit from the step module")
    try:
        step.dr, step.deposit_segment = proxy, counting
        run()
    finally:
        step.dr, step.deposit_segment = real_dr, original
    counts = [int(c) for c in np.asarray(proxy.counter) if c > 0]
    if not counts or proxy.calls >= proxy.SLOTS:
        raise RuntimeError(f"cannot attribute the deposit counts ({proxy.calls} scatters)")
    deposits = counts[0]
    return {
        "deposits": deposits,
        "scatter_sites_executed": len(counts),
        "scatters_traced": proxy.calls,
        "deposits_consistent": all(c == deposits for c in counts),
        "deposits_per_step": deposits / max(timed_march["steps"], 1),
        "mdeposits_per_s": deposits / 1e6 / timed_march["with_deposits_s"],
    }
