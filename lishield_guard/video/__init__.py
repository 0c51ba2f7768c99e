"""Videos: decode within limits, screen frames with the learned decision, add the evidence up.

`detect_video` screens a clip; `detect_media` screens whatever the bytes or the file name say
it is, with that media kind's detect function (`lishield_guard.batch.types.kind_of_source`:
a video, or else an image through `lishield_guard.detect`), for the service, `scan` and
`detect`. Modules in order: `decode`, `screen`, `calibrate`, `figure` (the settings are the
config's ``[video]`` group, `lishield_guard.settings.VideoConfig`).
"""

from __future__ import annotations

from lishield_guard.batch.types import VIDEO, kind_of_source
from lishield_guard.video.decode import VIDEO_SUFFIXES, is_video_bytes

__all__ = ["VIDEO_SUFFIXES", "detect_media", "detect_video", "is_video", "is_video_bytes"]


def is_video(source) -> bool:
    """Whether ``source`` (bytes, or a path) is a video: by its first bytes, or for a path
    whose bytes cannot be read here (missing, a FIFO: never opened blocking), by its name
    (`kind_of_source`)."""
    return kind_of_source(source) is VIDEO


def detect_video(source, config=None, vcfg=None):
    """`lishield_guard.video.screen.detect_video` (imported on first use), with one native
    thread or the process's own pin (`lishield_guard.threads.native_threads`)."""
    from lishield_guard.config import default_config
    from lishield_guard.threads import native_threads
    from lishield_guard.video.screen import detect_video as _detect_video

    with native_threads():
        return _detect_video(source, config or default_config(), vcfg)


def detect_media(source, config=None):
    """Screen ``source`` with the detect function of its media kind (`kind_of_source`).

    Returns
    -------
    Verdict
        A video's verdict holds ``evidence["video"]`` (per-frame scores, deciding frames).
    """
    return kind_of_source(source).detect(source, config)
