"""Perception: terrain map, textures, ground rendering, the downward camera and features."""
