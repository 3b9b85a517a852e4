"""The ``surface`` pipeline: classic two-pass photon mapping (Jensen), Steinhurst 2007's baseline."""
