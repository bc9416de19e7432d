"""Outputs: parameter files (and later LUTs, shader snippets, renderer exports)."""
