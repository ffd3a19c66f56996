"""Terrain contexts: clustering with persistent ids, feature streams and clustering metrics."""
