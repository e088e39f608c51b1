"""What the beams hit: triangle meshes, materials, OpenDRIVE roads, the assembled scene and its ray casters."""
