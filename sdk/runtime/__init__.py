"""Runtime: ``PoseEstimator`` (onnxruntime sessions, hypotheses, ICP refinement, results), tracking over a frame
source, overlays, and the CPU latency benchmark with its backend registry."""
