"""Stochastic progressive photon mapping (Hachisuka & Jensen 2009) and its memoryless variant
(Knaus & Zwicker 2011): :class:`SPPMPipeline`, :class:`SPPMParams`, :class:`BlockSums`."""

from .pipeline import STAGES, BlockSums, SPPMParams, SPPMPipeline

__all__ = ["STAGES", "BlockSums", "SPPMParams", "SPPMPipeline"]
