"""The ``screen`` pipeline: image-space photon mapping with image-space soft shadows (Yao 2011)."""
