"""Core: the icosahedral group, geometry, model presets, model metadata and the typed errors (numpy only)."""
