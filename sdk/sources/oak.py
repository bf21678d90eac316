"""Live OAK camera (depthai v3): stereo depth aligned to the colour camera, uint16 mm, per-frame intrinsics.

Convention: frames are ``depth`` [H, W] uint16 millimetres (0 = invalid; StereoDepth's default unit) aligned to the
colour camera CAM_A, ``rgb`` [H, W, 3] BGR uint8, ``K`` [3, 3] from each depth frame's ``ImgTransformation`` (falls back
to the device calibration of CAM_A at the requested size), ``timestamp`` seconds (device clock, host-synced).

Needs hardware: depthai is imported lazily (``DEPTHAI_LEVEL=error``) and a device is opened only when iteration
starts, so constructing an ``OakCamera`` never triggers a device search. Pipeline after luxonis'
``examples/python/ImageAlign/depth_align.py`` (RVC2: StereoDepth aligns to CAM_A; RVC4: a separate ImageAlign node).
"""
from __future__ import annotations

import datetime
import os

import numpy as np

from equipose.core.errors import ConfigError, SourceError
from equipose.sources._dai import import_depthai
from equipose.sources.base import Frame, FrameSource, register_source

__all__ = ["OakCamera"]


@register_source("oak", aliases=("oak", "oak:", "camera"))
class OakCamera(FrameSource):
    """Live frames from an OAK depth camera.

    Args:
        size: (W, H) of the depth/colour streams (default 640×400, the OAK-D stereo native size).
        fps: camera frame rate.
        device_id: a device MXID/IP to open (None: the first available).
        max_frames: stop after this many frames (None: until ``close()`` or the pipeline stops).
        search_timeout_ms: device search timeout (``DEPTHAI_SEARCH_TIMEOUT``); a missing device raises ``SourceError``.
    """

    def __init__(self, *, size=(640, 400), fps: float = 15.0, device_id: str | None = None,
                 max_frames: int | None = None, search_timeout_ms: int = 3000, queue_timeout_s: float = 5.0):
        try:
            self.size = (int(size[0]), int(size[1]))
        except (TypeError, ValueError, IndexError):
            raise ConfigError(f"size must be (width, height), got {size!r}") from None
        if not (self.size[0] > 0 and self.size[1] > 0 and fps > 0):
            raise ConfigError(f"size and fps must be positive, got size={size!r} fps={fps!r}")
        self.fps = float(fps)
        self.device_id = device_id
        self.max_frames = max_frames
        self.search_timeout_ms = int(search_timeout_ms)
        self.queue_timeout = datetime.timedelta(seconds=float(queue_timeout_s))
        self._pipeline = None
        self._device = None

    def _build(self, dai):
        try:
            device = dai.Device(dai.DeviceInfo(self.device_id)) if self.device_id else dai.Device()
        except RuntimeError as e:
            raise SourceError(f"no OAK camera could be opened ({e}); check the USB/PoE connection, or replay a "
                              "recording instead (FolderSource / McapReplay)") from None
        p = dai.Pipeline(device)
        size, fps = self.size, self.fps
        rgb = p.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_A)
        left = p.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_B)
        right = p.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_C)
        stereo = p.create(dai.node.StereoDepth).build(
            left.requestOutput(size, fps=fps), right.requestOutput(size, fps=fps),
            presetMode=dai.node.StereoDepth.PresetMode.DEFAULT)
        rgb_out = rgb.requestOutput(size, fps=fps, enableUndistortion=True)
        sync = p.create(dai.node.Sync)
        sync.setSyncThreshold(datetime.timedelta(seconds=1.0 / (2.0 * fps)))
        rgb_out.link(sync.inputs["rgb"])
        if device.getPlatform() == dai.Platform.RVC4:                           # OAK4: separate alignment node
            align = p.create(dai.node.ImageAlign)
            stereo.depth.link(align.input)
            rgb_out.link(align.inputAlignTo)
            align.outputAligned.link(sync.inputs["depth"])
        else:                                                                   # RVC2: align inside StereoDepth
            rgb_out.link(stereo.inputAlignTo)
            stereo.depth.link(sync.inputs["depth"])
        queue = sync.out.createOutputQueue(maxSize=4, blocking=False)
        K_calib = np.asarray(device.readCalibration().getCameraIntrinsics(dai.CameraBoardSocket.CAM_A, *size),
                             np.float64)                                        # [3, 3] at the stream size
        return device, p, queue, K_calib

    def __iter__(self):
        os.environ.setdefault("DEPTHAI_SEARCH_TIMEOUT", str(self.search_timeout_ms))  # before libdepthai reads it
        dai = import_depthai()
        device, p, queue, K_calib = self._build(dai)
        self._device, self._pipeline = device, p
        p.start()
        i = 0
        try:
            while p.isRunning() and (self.max_frames is None or i < self.max_frames):
                try:
                    group = queue.get(timeout=self.queue_timeout)               # dai.MessageGroup
                except dai.MessageQueue.QueueException:
                    return
                if group is None:
                    raise SourceError(f"no frame from the OAK camera within {self.queue_timeout.total_seconds()} s")
                dmsg, cmsg = group["depth"], group["rgb"]
                depth = np.asarray(dmsg.getFrame(), dtype=np.uint16)            # [H, W] mm, 0 = invalid
                tr = dmsg.getTransformation()
                K = np.asarray(tr.getIntrinsicMatrix(), np.float64) if tr.isValid() else K_calib
                yield Frame(depth=depth, K=K, depth_unit="mm", rgb=np.asarray(cmsg.getCvFrame()), index=i,
                            timestamp=dmsg.getTimestamp().total_seconds(), name=f"{dmsg.getSequenceNum():06d}")
                i += 1
        finally:
            self.close()

    def close(self):
        if self._pipeline is not None:
            try:
                self._pipeline.stop()
            finally:
                self._pipeline = None
        if self._device is not None:
            try:
                self._device.close()
            finally:
                self._device = None
