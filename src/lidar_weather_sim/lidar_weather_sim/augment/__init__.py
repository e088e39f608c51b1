"""Augmentation of recordings: synthetic weather (``augment``, :mod:`.weather`) and paper 4's synthetic
obstacles (``augment-obstacles``, :mod:`.obstacles`: boxes, other kinds, their raycast, occlusion and EPW)."""
