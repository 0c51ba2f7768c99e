"""Batch work in one place: the type table, the lister, the pool runner, the evidence cache.

`scan`, `calibrate` and `bench` (and the service's description of what it accepts) use these;
none of them lists files, pools workers or caches evidence in its own way.

- `lishield_guard.batch.types`: the one table of media kinds (suffixes, media types,
  signatures).
- `lishield_guard.batch.listing`: files, folders, lists and archives -> inputs.
- `lishield_guard.batch.pool`: workers initialised once, results as they arrive.
- `lishield_guard.batch.cache`: an opt-in evidence cache keyed by code and settings.
"""

from __future__ import annotations

from lishield_guard.batch.cache import EvidenceCache, code_version
from lishield_guard.batch.listing import (
    ARCHIVE_SUFFIXES,
    ScanItem,
    escape_name,
    is_archive,
    iter_items,
    list_files,
    unsafe_member_reason,
)
from lishield_guard.batch.pool import WorkerCrashed, progress_bar, run_pool, worker_state
from lishield_guard.batch.types import (
    IMAGE,
    IMAGE_MEDIA_TYPES,
    IMAGE_SUFFIXES,
    KINDS,
    VIDEO,
    VIDEO_MEDIA_TYPES,
    VIDEO_SUFFIXES,
    MediaKind,
    is_image_bytes,
    is_video_bytes,
    kind_of_bytes,
    kind_of_name,
)

__all__ = [
    "ARCHIVE_SUFFIXES",
    "IMAGE",
    "IMAGE_MEDIA_TYPES",
    "IMAGE_SUFFIXES",
    "KINDS",
    "VIDEO",
    "VIDEO_MEDIA_TYPES",
    "VIDEO_SUFFIXES",
    "EvidenceCache",
    "MediaKind",
    "ScanItem",
    "WorkerCrashed",
    "code_version",
    "escape_name",
    "is_archive",
    "is_image_bytes",
    "is_video_bytes",
    "iter_items",
    "kind_of_bytes",
    "kind_of_name",
    "list_files",
    "progress_bar",
    "run_pool",
    "unsafe_member_reason",
    "worker_state",
]
