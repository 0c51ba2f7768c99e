"""Videos: decode within limits, screen frames with the learned decision, add the evidence up.

`detect_video` screens a clip; `detect_media` screens whatever the bytes or the file name say
it is (a video, or else an image through `lishield_guard.detect`), for the service, `scan`
and `detect`. Modules in order: `settings`, `decode`, `screen`, `calibrate`.
"""

from __future__ import annotations

import os
from pathlib import Path

from lishield_guard.files import read_head
from lishield_guard.video.decode import VIDEO_SUFFIXES, is_video_bytes

__all__ = ["VIDEO_SUFFIXES", "detect_media", "detect_video", "is_video", "is_video_bytes"]


def is_video(source) -> bool:
    """Whether ``source`` (bytes, or a path) is a video: by its first bytes, or for a path
    whose bytes cannot be read here (missing, a FIFO: never opened blocking), by its name."""
    if isinstance(source, bytes | bytearray | memoryview):
        return is_video_bytes(bytes(source[:32]))
    if isinstance(source, str | os.PathLike):
        head = read_head(source, 32)
        if head is None:
            return Path(os.fspath(source)).suffix.lower() in VIDEO_SUFFIXES
        return is_video_bytes(head)
    return False


def detect_video(source, config=None, vcfg=None):
    """`lishield_guard.video.screen.detect_video` (imported on first use), with one native
    thread or the process's own pin (`lishield_guard.threads.native_threads`)."""
    from lishield_guard.config import default_config
    from lishield_guard.threads import native_threads
    from lishield_guard.video.screen import detect_video as _detect_video

    with native_threads():
        return _detect_video(source, config or default_config(), vcfg)


def detect_media(source, config=None):
    """Screen ``source`` as a video when it is one (`is_video`), else as an image.

    Returns
    -------
    Verdict
        A video's verdict holds ``evidence["video"]`` (per-frame scores, deciding frames).
    """
    if is_video(source):
        return detect_video(source, config)
    from lishield_guard.detector import detect

    return detect(source, config)
