"""Foundations every layer uses: configuration models, names, paths, the point layout, seeding, worker threads, rotations, paper 2's per-frame parameters."""
