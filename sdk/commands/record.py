"""``equipose record``: copy frames from any source (``oak``, .mcap, PNG folder, .pcd) to .mcap or a PNG folder.

Convention: ``-o X.mcap`` writes a depthai RecordMessage recording (RAW16 depth + per-frame intrinsics, colour to
``X.rgb.mcap``); any other ``-o`` is a PNG folder (``intrinsics.json``, ``depth/NNNNNN.png``, ``rgb/NNNNNN.png``).
Bad frames are reported on stderr and skipped.
"""
from __future__ import annotations

import pathlib
import sys

from equipose.core.errors import ConfigError

__all__ = ["add_arguments", "run"]


def add_arguments(p):
    p.add_argument("--source", "-s", required=True, help="'oak', a .mcap recording, a PNG folder, or .pcd file/folder")
    p.add_argument("--output", "-o", required=True, help="X.mcap (depthai recording) or a folder (PNG frames)")
    p.add_argument("--max-frames", type=int, default=None, help="stop after this many frames (default: all; "
                   "required for 'oak' unless you stop with Ctrl-C)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")


def run(args) -> int:
    from equipose.runtime.result import FrameError
    from equipose.sources import open_source
    from equipose.sources.folder import FolderWriter

    if args.max_frames is not None and args.max_frames < 1:
        raise ConfigError("--max-frames must be ≥ 1")
    out = pathlib.Path(args.output)
    if out.suffix.lower() == ".mcap":
        from equipose.sources.mcap import McapWriter
        writer = McapWriter(out, overwrite=args.overwrite)
    else:
        writer = FolderWriter(out, overwrite=args.overwrite)
    n = 0
    try:
        with open_source(args.source) as src:
            for i, frame in enumerate(src):
                if args.max_frames is not None and i >= args.max_frames:
                    break
                if isinstance(frame, FrameError):
                    print(f"frame {i}: skipped ({frame.error}: {frame.message})", file=sys.stderr)
                    continue
                writer.write(frame)
                n += 1
    except KeyboardInterrupt:
        print("stopped", file=sys.stderr)
    finally:
        writer.close()
    print(f"recorded {n} frame(s) to {out}")
    return 0 if n else 1
