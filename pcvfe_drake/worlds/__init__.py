"""Worlds as data: a world file (bounds, terrains with textures and frictions, regions, transition
strips, a course), its terrain raster and course, and generated worlds (docs/worlds.md)."""
