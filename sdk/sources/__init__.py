"""Depth frame sources (live OAK camera, .mcap replay, PNG folders, PCD files)."""
