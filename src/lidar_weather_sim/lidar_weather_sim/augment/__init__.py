"""Augmentation of recordings (entry points in :mod:`.command`): synthetic weather (``make-measured --on``, the
per-beam merge in :mod:`.weather`) and paper 4's synthetic obstacles (``augment``, :mod:`.obstacles`: boxes,
other kinds, their raycast, occlusion and EPW)."""
