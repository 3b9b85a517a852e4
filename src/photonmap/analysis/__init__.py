"""Tools that study a render rather than make one (Steinhurst 2007 Ch. 3, 4, 7): the photon-map
address stream of the final gathers, the LRU cache simulator and the hardware cost model."""
