"""Rebuild the bundled demo sample ``sdk/samples/table_mug`` from the PCL tutorial cloud (BSD-3).

Usage: python samples/make_table_mug.py [PATH/TO/table_scene_mug_stereo_textured.pcd]
Converts the organized 640×480 stereo cloud to the PNG-folder layout of ``equipose.sources.FolderSource``:
uint16 millimetre depth PNG, colour JPEG, intrinsics.json (K recovered by least squares from the organized cloud).
"""
from __future__ import annotations

import pathlib
import shutil
import sys

import cv2

from equipose.sources.folder import FolderWriter
from equipose.sources.pcd import PcdSource

ROOT = pathlib.Path(__file__).resolve().parents[1]
DEFAULT = ROOT.parent / "shared" / "data" / "kinect_pcl_objects" / "tutorials" / "table_scene_mug_stereo_textured.pcd"
OUT = ROOT / "sdk" / "samples" / "table_mug"


def main(src=DEFAULT):
    frame = next(iter(PcdSource(src)))
    keep = {n: (OUT / n).read_text() for n in ("NOTICE", "objects.json") if (OUT / n).is_file()}
    if OUT.exists():
        shutil.rmtree(OUT)
    with FolderWriter(OUT) as w:
        rgb, frame.rgb = frame.rgb, None
        w.write(frame)
    (OUT / "rgb").mkdir()
    cv2.imwrite(str(OUT / "rgb" / "000000.jpg"), rgb, [cv2.IMWRITE_JPEG_QUALITY, 90])
    for name, text in keep.items():                                             # hand-written files survive
        (OUT / name).write_text(text)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main(*sys.argv[1:])
