"""Training that accumulates across sessions: resumable slices and lanes over ``train/state/`` (``long_runs``),
copies of each saved step (``snapshots``) and their weight average (``averaging``)."""
