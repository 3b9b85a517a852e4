"""Vertex connection and merging (Georgiev et al. 2012): the ``vcm`` method."""

from .pipeline import VCMParams, VCMPipeline

__all__ = ["VCMParams", "VCMPipeline"]
