"""Steinhurst's photon-mapping chip as a functional cost model (Steinhurst 2007 Ch. 7, Tables 7.1,
7.7, 7.8, 7.10, 7.11). Where the chapter's numbers disagree (garbled figure captions, Table 7.11
against 7.10), the model takes Table 7.10's GB and GFLOP columns as its targets and recomputes
the derived ones.

One chip (ray caster, controller, photon gatherer; 90 GB/s, 500 GFLOPS) renders 16 × 16 tiles.
Per tile it spends the FLOPs of Table 7.7 and moves the inter-unit packets of Table 7.8; the
photon-map traffic comes from the cache simulator. The tile rate is the smaller of what memory
and arithmetic allow, ``tiles/s = min(90 GB/s ÷ bytes per tile, 500 GFLOPS ÷ FLOPs per tile)``,
and frames/s = tiles/s × chips / tiles per image (§7.5, linear in chips).

:func:`from_trace` feeds the model with the counts of a real render: final gathers per pixel,
kd-tree nodes visited per gather (instead of the 1.2 k rule of §7.3.4.1) and the simulated bytes
per image of a gather order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace


@dataclass(frozen=True)
class Chip:
    """Table 7.1's parameters (its nominal values) and the chip's limits."""

    P: int = 256  # pixels per tile
    T: int = 1024  # tiles per 512 × 512 image
    k: int = 100  # photons per gather
    N_S: int = 8  # shadow rays per eye-ray hit
    C_J: int = 32  # importance-sampling bins (4 × 8)
    L_IC: int = 4  # irradiance-cache links per cached pixel
    C_B1: int = 12  # partial BRDF evaluation, stage 1 (FLOPs)
    C_B2: int = 10  # partial BRDF evaluation, stage 2 (FLOPs)
    C_RayCast: int = 330  # one ray cast (FLOPs, SaarCOR)
    S_B: int = 13  # partially evaluated BRDF (bytes)
    examined: float | None = None  # photons examined per gather; None: the 1.2 k rule
    bandwidth: float = 90e9  # bytes/s per chip
    flops: float = 500e9  # FLOP/s per chip

    @property
    def C_G(self) -> float:
        """FLOPs of one k-NN gather: ``13 m + m log₂ m`` with ``m`` photons examined (§7.3.4.1,
        ``m = 1.2 k`` → 2,388.8 at k = 100)."""
        m = 1.2 * self.k if self.examined is None else self.examined
        return 13 * m + m * math.log2(m)


def flops_per_tile(n_fg: float, r_ic: float, chip: Chip = Chip()) -> dict:
    """Table 7.7: FLOPs per tile by task (the irradiance links in the Table's form,
    ``4 P R_IC L_IC N_FG``, not §7.3.3.1's: it reproduces Table 7.10; they differ by < 0.4 %)."""
    P, k, c = chip.P, chip.k, chip
    r_fg = 1 - r_ic
    rays = P * r_fg * n_fg
    return {
        "ray casting": P * (1 + r_fg * n_fg + c.N_S) * c.C_RayCast,
        "partial BRDF": P * (1 + r_fg * n_fg) * c.C_B1,
        "caustic gather": P * (c.C_G + k * (c.C_B2 + 1)),
        "IS/R_avg gather": P * (c.C_G + k),
        "indirect gathers": rays * (c.C_G + k * (c.C_B2 + 2)),
        "IC decisions": 5 * P * (P / 2),
        "combined cdf": P * r_fg * (3 * k + c.C_J * (c.C_B2 + 4)),
        "generate rays": 7 * rays,
        "accumulate gathers": 3 * P * (1 + r_fg * n_fg),
        "irradiance links": 4 * P * r_ic * c.L_IC * n_fg,
    }


def unit_traffic_per_tile(n_fg: float, r_ic: float, chip: Chip = Chip()) -> dict:
    """Table 7.8: bytes per tile on each on-chip link (Table 7.6's packet sizes as stated, not
    its field lists, which sum to 2 bytes less)."""
    P, S_B = chip.P, chip.S_B
    rays = P * (1 - r_ic) * n_fg
    return {
        "ray caster → controller": (S_B + 28) * P,
        "ray caster → gatherer": (S_B + 24) * rays,
        "controller → ray caster": 20 * rays,
        "controller → gatherer (caustic)": (S_B + 18) * P,
        "controller → gatherer (IS/R_avg)": 12 * P,
        "gatherer → controller (caustic)": 10 * P,
        "gatherer → controller (IS/R_avg)": (6 + 2 * chip.C_J) * P,
        "gatherer → controller (indirect)": 16 * rays,
    }


def performance(bytes_per_image: float, n_fg: float, r_ic: float, chip: Chip = Chip()) -> dict:
    """GFLOPs and GB per image, tiles/s allowed by memory and by arithmetic (Table 7.10), and
    frames/s for 1, 2, 4, 8 chips (Table 7.11)."""
    gflops = sum(flops_per_tile(n_fg, r_ic, chip).values()) * chip.T / 1e9
    gb = bytes_per_image / 1e9
    by_memory = chip.bandwidth / 1e9 * chip.T / gb if gb > 0 else math.inf
    by_compute = chip.flops / 1e9 * chip.T / gflops
    tiles = min(by_memory, by_compute)
    return {
        "GB_per_image": gb,
        "GFLOPs_per_image": gflops,
        "tiles_per_s_memory": by_memory,
        "tiles_per_s_compute": by_compute,
        "tiles_per_s": tiles,
        "fps": {chips: tiles * chips / chip.T for chips in (1, 2, 4, 8)},
    }


# Table 7.10 (Steinhurst 2007) with the N_FG and R_IC that reproduce its GFLOPs column
TABLE_7_10 = {
    "Cornell direct": (33, 0.0, 50.0, 37),
    "Cornell direct, optimized": (33, 0.62, 7.8, 16),
    "Cornell indirect": (300, 0.0, 391.0, 312),
    "Cornell indirect, optimized": (200, 0.46, 23.0, 115),
    "Glossy floor direct": (100, 0.0, 158.0, 106),
    "Glossy floor direct, optimized": (33, 0.08, 10.5, 34),
    "Glossy floor indirect": (300, 0.0, 426.0, 312),
    "Glossy floor indirect, optimized": (100, 0.08, 22.0, 98),
    "Sponza": (200, 0.0, 265.0, 209),
    "Sponza, optimized": (100, 0.36, 24.0, 69),
}


def from_trace(trace, bytes_by_order: dict, pixels: int, chip: Chip = Chip()) -> dict:
    """The model fed by a traced render (:class:`~.stream.GatherTrace`): final gathers per pixel
    and photons examined per gather as measured, and each order's simulated bytes scaled from
    ``pixels`` traced pixels to the chip's 512 × 512 image (no irradiance cache: R_IC = 0)."""
    n_fg = len(trace.batch) / pixels
    measured = replace(chip, examined=trace.visits / max(len(trace.batch), 1))
    scale = chip.P * chip.T / pixels
    return {
        order: performance(b * scale, n_fg, 0.0, measured) for order, b in bytes_by_order.items()
    }
