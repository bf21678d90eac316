"""Measuring and calibrating a trained network: the learned frame → category frame calibration (``calibration``),
batched torch inference (``inference``), the test-set harness behind ``equipose eval`` (``evaluate``) and the
ICP-60 baseline (``icp``)."""
