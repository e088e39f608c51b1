"""The learned per-point weather filter: its features (numba passes), the float32 MLP forward pass, the filter and
its training."""
