"""Typed errors raised by lishield-guard; the service and CLI map them to statuses and exit codes.

::

    LishieldError
    ├── ConfigError(LishieldError, ValueError)        bad detector / policy / config file values
    │   └── SpecError(ConfigError)                    a barcode spec breaks a validation rule
    ├── InvalidImageError(LishieldError, ValueError)  array input: ndim, empty, NaN, too few rows
    ├── ImageDecodeError(LishieldError)               bytes that cannot be decoded
    │   ├── UnsupportedImageError(ImageDecodeError)   not an image, or a format we do not read
    │   └── CorruptImageError(ImageDecodeError)       truncated or corrupt data of a known format
    ├── ImageTooLargeError(LishieldError)             too many pixels (decompression bomb cap)
    ├── PayloadTooLargeError(LishieldError)           too many bytes
    └── FirmwareError(LishieldError, ValueError)      a sequence cannot be compiled or read back

Every error carries a stable ``code`` string (used verbatim by the HTTP service and the scan
records), so callers never parse messages.
"""

from __future__ import annotations

__all__ = [
    "ConfigError",
    "CorruptImageError",
    "FirmwareError",
    "ImageDecodeError",
    "ImageTooLargeError",
    "InvalidImageError",
    "LishieldError",
    "PayloadTooLargeError",
    "SpecError",
    "UnsupportedImageError",
]


class LishieldError(Exception):
    """Base class of every error this project raises on purpose."""

    code = "lishield_error"


class ConfigError(LishieldError, ValueError):
    """A configuration value (detector, policy, config file) is invalid."""

    code = "invalid_config"


class SpecError(ConfigError):
    """A barcode spec breaks a validation rule; ``rule`` names the rule."""

    code = "invalid_spec"

    def __init__(self, message: str, *, rule: str) -> None:
        super().__init__(f"[{rule}] {message}")
        self.rule = rule


class InvalidImageError(LishieldError, ValueError):
    """An image array is unusable: wrong ndim, empty, non-finite, or too small."""

    code = "invalid_image"


class ImageDecodeError(LishieldError):
    """Bytes could not be decoded into an image."""

    code = "undecodable_image"


class UnsupportedImageError(ImageDecodeError):
    """The bytes are not an image, or are in a format this project does not read."""

    code = "unsupported_media_type"


class CorruptImageError(ImageDecodeError):
    """The bytes start like a known image format but are truncated or corrupt."""

    code = "undecodable_image"


class ImageTooLargeError(LishieldError):
    """The image declares more pixels than the configured cap (decompression bomb guard)."""

    code = "image_too_large"


class PayloadTooLargeError(LishieldError):
    """The encoded image has more bytes than the configured cap."""

    code = "payload_too_large"


class FirmwareError(LishieldError, ValueError):
    """A firmware sequence cannot be compiled within tolerance, or a file cannot be read back."""

    code = "firmware_error"
