"""Open a video within limits and decode only the frames a screen asks for, at the scale it needs.

PyAV (FFmpeg) reads MP4/MOV (H.264, HEVC) and WebM/MKV (VP8, VP9). `open_video` checks the
container's header against `VideoLimits` before any frame is decoded and lists the keyframes
from the container's index; `VideoReader.frames` decodes the requested frames in time order,
seeking to the keyframe before each one, so a frame costs the decode of its keyframe and of the
frames between them. Frames taller than twice ``max_rows`` are scaled down by a power of two
in the colour conversion (stripes need rows, not pixels; the photo path does the same in the
DCT domain). Pixels are never rotated: the rotation the container asks for is reported.
"""

from __future__ import annotations

import io
import math
import os
import stat
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lishield_guard.batch.types import VIDEO_SUFFIXES, is_video_bytes
from lishield_guard.errors import (
    CorruptVideoError,
    EmptyImageError,
    ImageTooLargeError,
    PayloadTooLargeError,
    SpecialFileError,
    UnsupportedImageError,
    VideoTooLongError,
    input_file_error,
)
from lishield_guard.settings import VideoLimits

__all__ = ["VIDEO_SUFFIXES", "DecodedFrame", "VideoInfo", "VideoReader", "ffmpeg_reason",
           "is_video_bytes", "open_video"]

DECODED_BYTES_PER_PIXEL = 1.5  # a decoded YUV 4:2:0 frame (what the decoder writes)


@dataclass(frozen=True)
class VideoInfo:
    """What the container says about its first video stream.

    Attributes
    ----------
    container, codec : str
        FFmpeg's names (``"mov,mp4,m4a,3gp,3g2,mj2"``, ``"h264"``).
    width, height : int
        Stored frame size in pixels (before rotation).
    frame_rate_hz : float
        Average frame rate.
    duration_s : float
        Duration of the video stream.
    n_frames : int
        Frame count (declared, or duration x frame rate when the container does not say).
    rotation_deg : int
        Clockwise display rotation the container asks for (0, 90, 180 or 270; the
        ``rotate`` tag or the display matrix).
    keyframes_s : tuple of float
        Times of the keyframes listed in the container's index (empty when it has none).
    n_bytes : int
        Size of the encoded file.
    """

    container: str
    codec: str
    width: int
    height: int
    frame_rate_hz: float
    duration_s: float
    n_frames: int
    rotation_deg: int
    keyframes_s: tuple[float, ...]
    n_bytes: int

    def to_dict(self) -> dict:
        """JSON-ready summary (the keyframe list as a count)."""
        return {"container": self.container.split(",")[0], "codec": self.codec,
                "width": self.width, "height": self.height,
                "frame_rate_hz": round(self.frame_rate_hz, 3),
                "duration_s": round(self.duration_s, 3), "n_frames": self.n_frames,
                "rotation_deg": self.rotation_deg, "n_keyframes": len(self.keyframes_s),
                "bytes": self.n_bytes}


@dataclass(frozen=True)
class DecodedFrame:
    """One decoded frame: RGB pixels in stored orientation, its time and index."""

    rgb: np.ndarray
    time_s: float
    index: int
    keyframe: bool
    row_scale: int


def _source_bytes(source, limits: VideoLimits) -> tuple[object, int]:
    """An object PyAV can open and the encoded size; refuses empty and oversized input."""
    if isinstance(source, bytes | bytearray | memoryview):
        n = len(source)
        if n == 0:
            raise EmptyImageError("empty video: no bytes")
        if n > limits.max_bytes:
            raise PayloadTooLargeError(f"video of {n} bytes exceeds max_bytes={limits.max_bytes}")
        return io.BytesIO(bytes(source)), n
    path = Path(os.fspath(source))
    try:
        st = path.stat()
    except OSError as exc:
        raise input_file_error(exc, str(path)) from exc
    if not stat.S_ISREG(st.st_mode):
        raise SpecialFileError(f"cannot read {str(path)!r}: not a regular file")
    n = st.st_size
    if n == 0:
        raise EmptyImageError(f"empty video: {path} has no bytes")
    if n > limits.max_bytes:
        raise PayloadTooLargeError(f"{path}: {n} bytes exceeds max_bytes={limits.max_bytes}")
    return str(path), n


def ffmpeg_reason(exc: BaseException) -> str:
    """FFmpeg's words for an error, without the errno tag and the ``'<none>'`` file name PyAV
    adds (``[Errno 1094995529] Invalid data found when processing input: '<none>'`` becomes
    ``Invalid data found when processing input``).

    Examples
    --------
    >>> ffmpeg_reason(OSError(1094995529, "Invalid data found when processing input", "<none>"))
    'Invalid data found when processing input'
    >>> ffmpeg_reason(ValueError("odd"))
    'odd'
    """
    words = getattr(exc, "strerror", None)
    return str(words) if words else str(exc)


def _first_frame(container, stream) -> tuple[int, object]:
    """The clip's first frame (decoded alone: it shows that the stream decodes at all, and the
    screen reuses it) and the clockwise display rotation (0, 90, 180 or 270): the older
    ``rotate`` tag, else the frame's display matrix (FFmpeg reports it counter-clockwise)."""
    import av

    try:
        frame = _keyframe(container, stream)
    except av.FFmpegError as exc:
        raise CorruptVideoError(f"the video's first frame cannot be decoded: "
                                f"{ffmpeg_reason(exc)}") from exc
    if frame is None:
        raise CorruptVideoError("the video stream has no frame")
    tag = stream.metadata.get("rotate")
    try:
        deg = float(tag) if tag is not None else -float(frame.rotation or 0)
    except ValueError:
        deg = 0.0
    return int(round(deg / 90.0)) * 90 % 360, frame


def _keyframe(container, stream):
    """The frame of the next packet alone (a keyframe after a seek), or None: the packet is
    decoded and the decoder drained at once, so the frames that follow it in decode order
    (B-frames a reordering decoder would wait for) are not decoded. The decoder is left
    flushed; the next decode must follow a seek."""
    for packet in container.demux(stream):
        if packet.dts is None:  # the demuxer's end-of-stream packet
            return None
        frames = [*stream.decode(packet), *stream.decode(None)]
        stream.codec_context.flush_buffers()
        if not frames:
            return None
        frames[0].time_base = stream.time_base  # what a demuxed decode sets
        return frames[0]
    return None


def _check_truncated(stream, n_bytes: int) -> None:
    """A container whose index points past the end of the file was cut short."""
    entries = stream.index_entries
    if entries is None or not len(entries):
        return
    last = entries[len(entries) - 1]
    if last.pos >= 0 and last.pos + last.size > n_bytes:
        raise CorruptVideoError(f"truncated video: its index needs {last.pos + last.size} "
                                f"bytes, the file has {n_bytes}")


class VideoReader:
    """An opened video (see `open_video`): its `info` and `frames` to decode."""

    def __init__(self, container, stream, info: VideoInfo, limits: VideoLimits,
                 first_frame=None) -> None:
        self._container = container
        self._first = first_frame  # decoded by open_video; the decoder is left drained
        self._stream = stream
        self.info = info
        self.limits = limits
        self.decoded_frames = 0  # frames the decoder produced, kept or not (the work done)
        self.budget_hit = False  # the decode budget (`max_decoded_frames`) stopped a decode
        self._at_end = True  # the next decode seeks (open_video drained the decoder)
        self.decoded_frames = 1 if first_frame is not None else 0
        frame_bytes = info.width * info.height * DECODED_BYTES_PER_PIXEL
        #: decode budget: `VideoLimits.max_decoded_frames`, fewer for frames so large that
        #: `VideoLimits.max_decoded_bytes` is reached first
        self.max_decoded_frames = max(1, min(limits.max_decoded_frames,
                                             int(limits.max_decoded_bytes // frame_bytes)))
        self._tb = float(stream.time_base)
        self._start = float(stream.start_time or 0) * self._tb

    def __enter__(self) -> VideoReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Release the container."""
        self._container.close()

    def row_scale(self, max_rows: int) -> int:
        """Power-of-two factor by which frames are scaled down so that at least ``max_rows``
        rows stay (1 when ``max_rows`` is 0 or the frame is short enough)."""
        scale = 1
        while max_rows and self.info.height // (2 * scale) >= max_rows:
            scale *= 2
        return scale

    def frames(self, times_s, *, max_rows: int = 0) -> Iterator[DecodedFrame]:
        """Decode the frames at (or just after) ``times_s``, in time order.

        Each target seeks to the keyframe before it unless the previous target's decode is
        already nearer; the decode stops when `max_decoded_frames` frames have
        been produced in all (the caller sees fewer frames, never a partial one).

        Raises
        ------
        CorruptVideoError
            The stream cannot be decoded where the container says it has frames.
        """
        scale = self.row_scale(max_rows)
        w, h = self.info.width // scale, self.info.height // scale
        pos_s = -math.inf  # time of the last decoded frame
        fps = max(self.info.frame_rate_hz, 1e-3)
        for t in sorted(float(x) for x in times_s):
            if self._first is not None and self._first.time is not None and \
                    abs(self._first.time - self._start - t) < 0.5 / fps:
                frame = self._first  # the first frame, decoded when the clip was opened
            else:
                frame = self._seek_and_decode(t, pos_s, fps)
            if frame is None:
                return
            pos_s = float(frame.time) - self._start
            rgb = frame.to_ndarray(format="rgb24", width=w, height=h,
                                   interpolation="AREA") if scale > 1 else \
                frame.to_ndarray(format="rgb24")
            yield DecodedFrame(rgb=rgb, time_s=pos_s, index=int(round(pos_s * fps)),
                               keyframe=bool(frame.key_frame), row_scale=scale)

    def _seek_and_decode(self, t: float, pos_s: float, fps: float):
        """The frame at ``t``: seek to the keyframe before it unless decoding on from
        ``pos_s`` is nearer; a target on a keyframe is decoded alone."""
        gap_frames = (t - pos_s) * fps
        prev_key = max((k for k in self.info.keyframes_s if k <= t + 0.5 / fps),
                       default=None)
        if self._at_end or not (0 <= gap_frames and (prev_key is None or prev_key <= pos_s)):
            self._at_end = False
            self._container.seek(int((t + self._start) / self._tb), stream=self._stream,
                                 backward=True, any_frame=False)
            at_key = prev_key is not None and abs(t - prev_key) < 0.5 / fps
            if at_key and self.decoded_frames >= self.max_decoded_frames:
                self.budget_hit = True
                return None
            frame = _keyframe(self._container, self._stream) if at_key else None
            if frame is not None:  # the keyframe alone: the decoder was drained
                self.decoded_frames += 1
                self._at_end = True
                if frame.time is None or frame.time - self._start < t - 0.5 / fps:
                    # the index put a keyframe at t, the stream did not: decode up to t
                    self._at_end = False
                    self._container.seek(int((t + self._start) / self._tb),
                                         stream=self._stream, backward=True, any_frame=False)
                    frame = None
        else:
            frame = None
        return frame or self._decode_until(t, fps)

    def _decode_until(self, t_s: float, fps: float):
        """The first frame at or after ``t_s``; the last frame when the stream ends first;
        None over the budget or when the stream has no frame there."""
        import av

        last = None
        try:
            for frame in self._container.decode(self._stream):
                self.decoded_frames += 1
                if self.decoded_frames > self.max_decoded_frames:
                    self.budget_hit = True
                    return None
                last = frame
                if frame.time is not None and frame.time - self._start >= t_s - 0.5 / fps:
                    return frame
        except av.EOFError:
            pass
        except av.FFmpegError as exc:
            raise CorruptVideoError(f"video stream cannot be decoded near {t_s:.2f} s: "
                                    f"{ffmpeg_reason(exc)}") from exc
        self._at_end = True
        return last


def open_video(source, limits: VideoLimits | None = None) -> VideoReader:
    """Open ``source`` (bytes, or a path) and check its header against ``limits``.

    Returns
    -------
    VideoReader
        Use as a context manager; nothing is decoded yet.

    Raises
    ------
    EmptyImageError, PayloadTooLargeError
        No bytes, or more than ``max_bytes``.
    UnsupportedImageError
        Not a container FFmpeg reads, or no video stream in it.
    CorruptVideoError
        A known container that is cut short or broken.
    VideoTooLongError
        Longer than ``max_duration_s`` or more frames than ``max_frames``.
    ImageTooLargeError
        Frames of more than ``max_frame_pixels`` pixels.
    """
    import av

    limits = limits or VideoLimits()
    src, n_bytes = _source_bytes(source, limits)
    head = src.getvalue()[:16] if isinstance(src, io.BytesIO) else _head(src)
    try:
        container = av.open(src, mode="r", metadata_errors="ignore")
    except av.InvalidDataError as exc:
        if is_video_bytes(head):
            raise CorruptVideoError(f"broken or truncated video container: "
                                    f"{ffmpeg_reason(exc)}") from exc
        raise UnsupportedImageError(f"not a video FFmpeg reads: {ffmpeg_reason(exc)}") from exc
    except (av.FFmpegError, OSError) as exc:
        raise UnsupportedImageError(f"cannot open video: {ffmpeg_reason(exc)}") from exc
    try:
        if "image" in container.format.name or container.format.name.endswith("_pipe"):
            raise UnsupportedImageError(f"a still image ({container.format.name}), not a video")
        return _reader(container, n_bytes, limits)
    except CorruptVideoError as exc:
        container.close()
        if is_video_bytes(head):
            raise
        raise UnsupportedImageError(f"not a video this screen reads: {exc}") from exc
    except BaseException:
        container.close()
        raise


def _head(path: str) -> bytes:
    with open(path, "rb") as fh:
        return fh.read(16)


def _reader(container, n_bytes: int, limits: VideoLimits) -> VideoReader:
    if not container.streams:  # a clip cut before its index (an MP4's moov at the end)
        raise CorruptVideoError("the container lists no stream: cut short before its index, "
                                "or broken")
    if not container.streams.video:
        raise UnsupportedImageError("no video stream in the container")
    stream = container.streams.video[0]
    cc = stream.codec_context
    if cc is None:  # FFmpeg found no codec for the stream (e.g. a broken sample entry)
        raise UnsupportedImageError("no decoder for the video stream's codec")
    codec = cc.name
    if cc.codec is None or not cc.codec.is_decoder:
        raise UnsupportedImageError(f"no decoder for video codec {codec!r}")
    cc.thread_count = 1  # one thread per clip: the cost budget is per thread
    width, height = int(cc.width), int(cc.height)
    if width < 1 or height < 1:
        raise CorruptVideoError("video stream without a frame size")
    if width * height > limits.max_frame_pixels:
        raise ImageTooLargeError(f"video frames of {width}x{height} exceed max_frame_pixels="
                                 f"{limits.max_frame_pixels}")
    tb = float(stream.time_base) if stream.time_base else 0.0
    rate = float(stream.average_rate or stream.guessed_rate or 0.0)
    duration_s = float(stream.duration) * tb if stream.duration else 0.0
    if duration_s <= 0 and container.duration:
        duration_s = container.duration / 1e6
    n_frames = int(stream.frames) or int(round(duration_s * rate))
    if duration_s > limits.max_duration_s:
        raise VideoTooLongError(f"video of {duration_s:.1f} s exceeds max_duration_s="
                                f"{limits.max_duration_s:g}")
    if n_frames > limits.max_frames:
        raise VideoTooLongError(f"video of {n_frames} frames exceeds max_frames="
                                f"{limits.max_frames}")
    if rate <= 0 or duration_s <= 0:
        raise CorruptVideoError("video stream without a frame rate or duration")
    _check_truncated(stream, n_bytes)
    start = float(stream.start_time or 0) * tb
    entries = stream.index_entries or ()
    keys = sorted(float(e.timestamp) * tb - start for e in entries if e.is_keyframe)
    if keys and keys[0] < 0:  # index times are decode times: the first keyframe shows at 0
        keys = [k - keys[0] for k in keys]
    rotation, first = _first_frame(container, stream)
    info = VideoInfo(container=container.format.name, codec=codec, width=width, height=height,
                     frame_rate_hz=rate, duration_s=duration_s, n_frames=n_frames,
                     rotation_deg=rotation, keyframes_s=tuple(keys), n_bytes=n_bytes)
    return VideoReader(container, stream, info, limits, first)
