"""Snapshots of a training lane for weight averaging: a copy of each model's ``latest.pt`` per saved step,
``DEST/<name>/<step, 9 digits>.pt`` (``python -m equipose.train.lanes.long_runs run --snapshots DEST``; averaged by
``python -m equipose.train.lanes.averaging``)."""
from __future__ import annotations

import os
import pathlib
import shutil
import threading

__all__ = ["SnapshotCopier"]


class SnapshotCopier:
    """Copies of each model's ``latest.pt`` as training goes on: ``dest/<name>/<step, 9 digits>.pt``, one per saved
    step (the trainer replaces ``latest.pt`` atomically, so a copy is always a whole checkpoint). ``poll()`` copies
    what changed since the last call; ``start()`` polls every ``every`` seconds in a daemon thread until ``stop()``."""

    def __init__(self, names: list, dest, *, state_dir, every: float = 120.0):
        self.names, self.every = list(names), float(every)
        self.dest, self.state_dir = pathlib.Path(dest), pathlib.Path(state_dir)
        self._seen: dict = {}
        self._stop = None
        self._thread = None

    def poll(self) -> list:
        """Copy every ``latest.pt`` whose modification time changed; return the new snapshot paths."""
        import torch
        made = []
        for name in self.names:
            src = self.state_dir / name / "latest.pt"
            try:
                stamp = src.stat().st_mtime_ns
            except FileNotFoundError:
                continue
            if self._seen.get(name) == stamp:
                continue
            folder = self.dest / name
            folder.mkdir(parents=True, exist_ok=True)
            tmp = folder / f".{name}.tmp"
            shutil.copyfile(src, tmp)
            step = int(torch.load(tmp, map_location="cpu", weights_only=True).get("step", 0))
            out = folder / f"{step:09d}.pt"
            if out.exists():
                tmp.unlink()
            else:
                os.replace(tmp, out)
                made.append(out)
            self._seen[name] = stamp
        return made

    def start(self) -> "SnapshotCopier":
        self._stop = threading.Event()

        def loop():
            while not self._stop.is_set():
                try:
                    self.poll()
                except (OSError, RuntimeError):           # a file replaced mid-copy: the next poll copies it again
                    pass
                self._stop.wait(self.every)

        self._thread = threading.Thread(target=loop, name="equipose-snapshots", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        if self._stop is not None:
            self._stop.set()
            self._thread.join()
        self.poll()                                           # the slice's last checkpoint
