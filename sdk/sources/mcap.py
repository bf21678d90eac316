"""depthai ``.mcap`` recordings: ``McapReplay`` (ReplayMessage) and ``McapWriter`` (RecordMessage), host-only.

Convention: the depth stream is one ``.mcap`` of RAW16 ``ImgFrame`` messages (uint16 millimetres, 0 = invalid), each
carrying its intrinsics in its ``ImgTransformation`` (per-frame K, so resolution changes survive). An optional colour
stream lives beside it as ``<stem>.rgb.mcap`` (BGR888i frames, paired by order). Both nodes run in a host-only pipeline
(``dai.Pipeline(createImplicitDevice=False)``), so no device search ever starts; the same nodes record a live OAK.
Timestamps are seconds (``ImgFrame.getTimestamp()``).
"""
from __future__ import annotations

import datetime
import os
import pathlib
import time

import numpy as np

from equipose.core.errors import SourceError
from equipose.core.frame_error import FrameError
from equipose.core.intrinsics import check_intrinsics
from equipose.sources._dai import import_depthai
from equipose.sources.base import Frame, FrameSource, register_source

__all__ = ["McapReplay", "McapWriter", "rgb_path_for", "mcap_message_count"]


MCAP_MAGIC = b"\x89MCAP0\r\n"
MIN_MESSAGE_BYTES = 31          # a Message record without payload: opcode, length, channel, sequence, 2 timestamps


def mcap_message_count(path) -> int | None:
    """Message count from an .mcap file's summary Statistics record (None if the file has no summary).

    MCAP layout (spec): ... Footer record [opcode 0x02, u64 length, u64 summary_start, u64 summary_offset_start,
    u32 crc] + 8-byte magic. The summary section holds a Statistics record (opcode 0x0B) whose first field is the u64
    message count. Raises ``SourceError`` when the footer points outside the file or the count is impossible for the
    file's size (a damaged or forged recording).
    """
    import struct
    size = os.path.getsize(path)
    if size < 8 + 37:
        return None
    with open(path, "rb") as f:
        f.seek(size - 37)
        tail = f.read(37)
        if tail[-8:] != MCAP_MAGIC or tail[0] != 0x02:
            return None
        summary_start, summary_offset_start = struct.unpack_from("<QQ", tail, 9)
        if summary_start == 0:
            return None
        end = summary_offset_start if summary_offset_start else size - 37
        if not 8 <= summary_start <= end <= size - 37:
            raise SourceError(f"{path}: the MCAP footer points outside the file (summary at {summary_start}, file "
                              f"{size} bytes); the recording is damaged")
        f.seek(summary_start)
        data = f.read(end - summary_start)
    pos = 0
    while pos + 9 <= len(data):
        op, length = data[pos], struct.unpack_from("<Q", data, pos + 1)[0]
        if op == 0x0B and length >= 8 and pos + 17 <= len(data):
            count = int(struct.unpack_from("<Q", data, pos + 9)[0])
            per_channel = _channel_counts(data[pos + 9: pos + 9 + length])
            if count > size // MIN_MESSAGE_BYTES or (per_channel is not None and sum(per_channel) != count):
                raise SourceError(f"{path}: its statistics claim {count} messages, inconsistent with its per-channel "
                                  f"counts {per_channel} or its size ({size} bytes); the recording is damaged")
            return count
        pos += 9 + length
    return None


def _channel_counts(stats: bytes) -> list | None:
    """Per-channel message counts of a Statistics record body (None if it is too short to hold them).

    Body: u64 message_count, u16 schema_count, u32 channel_count, u32 attachment_count, u32 metadata_count,
    u32 chunk_count, u64 message_start_time, u64 message_end_time, then map<u16 channel, u64 count> (u32 byte length).
    """
    import struct
    head = 8 + 2 + 4 * 4 + 8 + 8
    if len(stats) < head + 4:
        return None
    n = struct.unpack_from("<I", stats, head)[0]
    if n % 10 or head + 4 + n > len(stats):
        return None
    return [struct.unpack_from("<Q", stats, head + 4 + k + 2)[0] for k in range(0, n, 10)]


def rgb_path_for(path) -> pathlib.Path:
    """``x.mcap`` → ``x.rgb.mcap`` (the colour stream beside a depth recording)."""
    p = pathlib.Path(path)
    return p.with_name(p.stem + ".rgb.mcap")


@register_source("mcap", suffixes=(".mcap",))
class McapReplay(FrameSource):
    """Replay a depth ``.mcap`` recorded by ``McapWriter`` / ``equipose record`` / a depthai RecordMessage node.

    Args: path of the depth .mcap; ``rgb`` path of the colour .mcap (default: ``<stem>.rgb.mcap`` if present, else
    none); ``timeout_s`` how long to wait for the next message before treating the stream as ended.
    Frames whose type is not RAW16 or whose intrinsics are missing are yielded as ``FrameError`` records.
    """

    def __init__(self, path, *, rgb=None, timeout_s: float = 2.0):
        self.path = pathlib.Path(path)
        if not self.path.is_file():
            raise SourceError(f"recording {self.path} does not exist")
        if self.path.stat().st_size < 16:
            raise SourceError(f"{self.path} is too small to be an .mcap recording")
        with open(self.path, "rb") as f:
            if f.read(8) != MCAP_MAGIC:
                raise SourceError(f"{self.path} is not an .mcap file (bad magic); record with 'equipose record'")
            f.seek(-8, os.SEEK_END)
            if f.read(8) != MCAP_MAGIC:
                raise SourceError(f"{self.path} has no MCAP footer: the recording was cut off before it was closed "
                                  "(or is damaged) and cannot be replayed")
        auto = rgb_path_for(self.path)
        self.rgb_path = pathlib.Path(rgb) if rgb is not None else (auto if auto.is_file() else None)
        self.timeout = datetime.timedelta(seconds=float(timeout_s))
        self.count = mcap_message_count(self.path)
        self._pipeline = None
        self._queues = None

    def _open(self, dai):
        p = dai.Pipeline(createImplicitDevice=False)
        queues = []
        for path in [self.path] + ([self.rgb_path] if self.rgb_path else []):
            node = p.create(dai.node.ReplayMessage)
            node.setReplayFile(str(path))
            # With two streams a finished node stops the whole pipeline and drops the other stream's queued messages,
            # so with a known message count both nodes loop and we stop after ``count`` frames; a single stream (or
            # no count) plays once.
            node.setLoop(self.count is not None and self.rgb_path is not None)
            queues.append(node.out.createOutputQueue(maxSize=8, blocking=True))
        p.start()
        self._queues = queues
        return p, queues

    def _get(self, q, dai):
        try:
            return q.get(timeout=self.timeout)
        except dai.MessageQueue.QueueException:                                 # closed: the replay ended
            return None
        except RuntimeError:
            return None

    def __iter__(self):
        dai = import_depthai()
        p, queues = self._open(dai)
        self._pipeline = p
        try:
            i = 0
            while self.count is None or i < self.count:
                msg = self._get(queues[0], dai)
                if msg is None:
                    break
                rgb = None
                if len(queues) > 1:
                    cm = self._get(queues[1], dai)
                    rgb = None if cm is None else np.asarray(cm.getCvFrame())
                yield self._to_frame(msg, rgb, i, dai)
                i += 1
            if i == 0:
                raise SourceError(f"{self.path}: no message could be replayed; the file is not a depthai recording "
                                  "or is damaged")
        finally:
            self.close()

    @staticmethod
    def _to_frame(msg, rgb, i, dai):
        if not isinstance(msg, dai.ImgFrame):
            return FrameError(i, "SourceError", f"message {i} is a {type(msg).__name__}, not an ImgFrame")
        if msg.getType() != dai.ImgFrame.Type.RAW16:
            return FrameError(i, "DepthDtypeError", f"message {i} is {msg.getType()}, expected RAW16 depth (uint16 mm)")
        tr = msg.getTransformation()
        if not tr.isValid():
            return FrameError(i, "IntrinsicsError", f"message {i} carries no intrinsics (invalid ImgTransformation); "
                              "record frames with ImgTransformation(width, height, K) set")
        depth = np.asarray(msg.getFrame(), dtype=np.uint16)                     # [H, W] mm
        K = np.asarray(tr.getIntrinsicMatrix(), np.float64)                     # [3, 3]
        w, h = tr.getSize()
        ts = msg.getTimestamp().total_seconds()
        return Frame(depth=depth, K=K, depth_unit="mm", rgb=rgb, index=i, timestamp=ts,
                     image_size=(int(w), int(h)), name=f"{msg.getSequenceNum():06d}")

    def close(self):
        if self._pipeline is not None:
            try:
                for q in self._queues or []:
                    q.close()                                                   # unblocks nodes waiting to send
                self._pipeline.stop()
            finally:
                self._pipeline, self._queues = None, None


class McapWriter:
    """Record frames to a depth ``.mcap`` (+ ``<stem>.rgb.mcap`` when frames carry colour). Context manager.

    Every frame is sent as a RAW16 ``ImgFrame`` with ``ImgTransformation(W, H, K)``, sequence number and timestamp.
    """

    def __init__(self, path, *, overwrite: bool = False):
        self.path = pathlib.Path(path)
        if self.path.suffix.lower() != ".mcap":
            raise SourceError(f"{self.path}: McapWriter writes .mcap files")
        if self.path.exists() and not overwrite:
            raise SourceError(f"{self.path} exists; choose a new name or pass overwrite=True")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._dai = import_depthai()
        self._pipeline = None
        self._queues = None
        self.count = 0

    def _start(self, with_rgb: bool):
        dai = self._dai
        p = dai.Pipeline(createImplicitDevice=False)
        queues = []
        for path in [self.path] + ([rgb_path_for(self.path)] if with_rgb else []):
            node = p.create(dai.node.RecordMessage)
            node.setRecordFile(str(path))
            node.input.setBlocking(True)
            node.input.setMaxSize(1)                                            # send() waits for the writer
            queues.append(node.input.createInputQueue(maxSize=1, blocking=True))
        p.start()
        self._pipeline, self._queues = p, queues

    def write(self, frame: Frame):
        """Append one frame (depth uint16 mm)."""
        dai = self._dai
        depth = np.asarray(frame.depth)
        if depth.dtype != np.uint16 or frame.depth_unit != "mm":
            raise SourceError(f"McapWriter records uint16 millimetres; got {depth.dtype} with depth_unit "
                              f"{frame.depth_unit!r} — convert first: (depth_m * 1000).round().astype(np.uint16)")
        if self._pipeline is None:
            self._start(frame.rgb is not None)
        H, W = depth.shape
        K = np.asarray(frame.K, np.float64)
        if frame.image_size is not None and tuple(frame.image_size) != (W, H):
            K = check_intrinsics(K, (H, W), frame.image_size)                   # store K for the stored size
        ts = datetime.timedelta(seconds=float(frame.timestamp if frame.timestamp is not None else self.count / 30.0))
        m = dai.ImgFrame()
        m.setCvFrame(np.ascontiguousarray(depth), dai.ImgFrame.Type.RAW16)
        m.setTransformation(dai.ImgTransformation(W, H, K.tolist()))
        m.setSequenceNum(self.count)
        m.setTimestamp(ts)
        self._queues[0].send(m)
        if len(self._queues) > 1:
            c = dai.ImgFrame()
            rgb = frame.rgb if frame.rgb is not None else np.zeros((H, W, 3), np.uint8)
            c.setCvFrame(np.ascontiguousarray(rgb), dai.ImgFrame.Type.BGR888i)
            c.setSequenceNum(self.count)
            c.setTimestamp(ts)
            self._queues[1].send(c)
        self.count += 1

    def close(self, settle_s: float = 0.15, timeout_s: float = 10.0):
        """Wait until the recording files stop growing (the writer drained its queue), then stop the pipeline."""
        if self._pipeline is None:
            return
        files = [self.path] + ([rgb_path_for(self.path)] if len(self._queues) > 1 else [])
        last, t_end, stable_since = None, time.monotonic() + timeout_s, time.monotonic()
        while time.monotonic() < t_end:
            sizes = tuple(os.path.getsize(f) if os.path.exists(f) else -1 for f in files)
            if sizes != last:
                last, stable_since = sizes, time.monotonic()
            elif time.monotonic() - stable_since >= settle_s:
                break
            time.sleep(0.03)
        self._pipeline.stop()
        self._pipeline = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
