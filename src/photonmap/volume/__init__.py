"""The ``volume`` pipeline: Sun et al. 2008 as re-implemented by Pfeuti 2009 §3.1."""
