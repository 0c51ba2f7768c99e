"""Typed errors raised by lishield-guard; the service and CLI map them to statuses and exit codes.

::

    LishieldError
    ├── ConfigError(LishieldError, ValueError)        bad detector / policy / config file values
    │   └── SpecError(ConfigError)                    a barcode spec breaks a validation rule
    ├── InvalidImageError(LishieldError, ValueError)  array input: ndim, empty, NaN, too few rows
    ├── ImageDecodeError(LishieldError)               bytes that cannot be decoded
    │   ├── UnsupportedImageError(ImageDecodeError)   not an image, or a format we do not read
    │   │   └── EmptyImageError(UnsupportedImageError) no bytes at all (an empty file or body)
    │   └── CorruptImageError(ImageDecodeError)       truncated or corrupt data of a known format
    ├── ImageTooLargeError(LishieldError)             too many pixels (decompression bomb cap)
    ├── PayloadTooLargeError(LishieldError)           too many bytes
    ├── InputFileError(LishieldError, OSError)        an input file that cannot be read
    │   ├── InputNotFoundError(.., FileNotFoundError) no such file (or a dangling link)
    │   └── SpecialFileError(InputFileError)          a FIFO, device, socket or folder
    └── FirmwareError(LishieldError, ValueError)      a sequence cannot be compiled or read back

Every error carries a stable ``code`` string (used verbatim by the HTTP service and the scan
records), so callers never parse messages. `ERROR_CODES` is the one table of every code that
any interface reports: its HTTP status(es), the CLI exit status it leads to, and its meaning.
The service's statuses and code enum, the scanner's record codes, the CLI's exit statuses, the
README's exit-status table and docs/service.md's code table are all read from it
(`exit_status_table_markdown`, `error_code_table_markdown`). `classify` is the one mapping
from any exception to its code and message, used by ``detect``, ``scan`` and the service
alike (the Python API raises the typed errors themselves).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "ERROR_CODES",
    "EXIT_INPUT_ERROR",
    "EXIT_MEANINGS",
    "EXIT_USAGE",
    "ConfigError",
    "CorruptImageError",
    "CorruptVideoError",
    "EmptyImageError",
    "ErrorCodeInfo",
    "FirmwareError",
    "ImageDecodeError",
    "InputFileError",
    "InputNotFoundError",
    "ImageTooLargeError",
    "InvalidImageError",
    "LishieldError",
    "PayloadTooLargeError",
    "SpecError",
    "SpecialFileError",
    "UnsupportedImageError",
    "VideoTooLongError",
    "classify",
    "error_code",
    "error_code_table_markdown",
    "exit_status_table_markdown",
    "input_file_error",
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
        self._message = message

    def __reduce__(self):
        """Picklable (to and from detection worker processes) despite the keyword argument."""
        return _spec_error, (self._message, self.rule)


def _spec_error(message: str, rule: str) -> SpecError:
    return SpecError(message, rule=rule)


class InvalidImageError(LishieldError, ValueError):
    """An image array is unusable: wrong ndim, empty, non-finite, or too small."""

    code = "invalid_image"


class ImageDecodeError(LishieldError):
    """Bytes could not be decoded into an image."""

    code = "undecodable_image"


class UnsupportedImageError(ImageDecodeError):
    """The bytes are not an image, or are in a format this project does not read."""

    code = "unsupported_media_type"


class EmptyImageError(UnsupportedImageError):
    """There are no bytes at all: an empty file, upload or request body."""

    code = "empty_body"


class CorruptImageError(ImageDecodeError):
    """The bytes start like a known image format but are truncated or corrupt."""

    code = "undecodable_image"


class ImageTooLargeError(LishieldError):
    """The image declares more pixels than the configured cap (decompression bomb guard)."""

    code = "image_too_large"


class PayloadTooLargeError(LishieldError):
    """The encoded image has more bytes than the configured cap."""

    code = "payload_too_large"


class CorruptVideoError(ImageDecodeError):
    """The bytes are a known video container, but it is cut short, broken or cannot be
    decoded where it says it has frames."""

    code = "undecodable_video"


class VideoTooLongError(LishieldError):
    """The video is longer (seconds or frames) than the configured cap."""

    code = "video_too_long"


class InputFileError(LishieldError, OSError):
    """An input file that cannot be read (permissions, a loop of links, an I/O error)."""

    code = "read_error"


class InputNotFoundError(InputFileError, FileNotFoundError):
    """No input file at the path (or a link whose target is gone)."""

    code = "not_found"


class SpecialFileError(InputFileError):
    """The path is a FIFO, a device, a socket or a folder: never read as an image."""

    code = "special_member"


def input_file_error(exc: OSError, shown: str) -> InputFileError:
    """The typed error of an `OSError` met opening or reading input file ``shown``.

    Examples
    --------
    >>> input_file_error(FileNotFoundError(2, "No such file or directory"), "x.jpg").code
    'not_found'
    >>> str(input_file_error(OSError(40, "Too many levels of symbolic links"), "loop.jpg"))
    "cannot read 'loop.jpg': Too many levels of symbolic links"
    """
    cls = InputNotFoundError if isinstance(exc, FileNotFoundError) else InputFileError
    return cls(f"cannot read {shown!r}: {exc.strerror or exc}")


class FirmwareError(LishieldError, ValueError):
    """A firmware sequence cannot be compiled within tolerance, or a file cannot be read back."""

    code = "firmware_error"


# ----------------------------------------------------------------------------- the code table

EXIT_USAGE = 2  # `lishield_guard.commands.ExitCode.USAGE`: bad arguments or config
EXIT_INPUT_ERROR = 3  # `ExitCode.ERROR`: an input could not be screened (never "clean")
#: What each CLI exit status means (`lishield_guard.commands.ExitCode` has the same values).
EXIT_MEANINGS = {0: "every image analysed and clean (or the command succeeded)",
                 1: "at least one image carries a policy barcode (wins over errors)",
                 EXIT_USAGE: "usage error: bad arguments or config",
                 EXIT_INPUT_ERROR: "no image protected, but an input error (a missing, empty or "
                                   "unreadable input) or an image the detector could not look "
                                   "at (undetermined, never clean)"}


@dataclass(frozen=True)
class ErrorCodeInfo:
    """One stable error code and what every interface does with it.

    Attributes
    ----------
    code : str
        The ``code`` of HTTP error bodies, scan records and CLI error lines.
    http_statuses : tuple of int
        HTTP statuses answered with it (first: the usual one); empty when the service never
        answers it (scan-only codes, config errors, which stop the service at startup).
    exit_status : int or None
        CLI exit status when this is the worst outcome (`EXIT_USAGE` or `EXIT_INPUT_ERROR`;
        a protected image elsewhere in the same run still exits 1); None for HTTP-only codes.
    source : str
        ``"core"`` (a `LishieldError` subclass), ``"scan"`` (the scanner's own skip reasons)
        or ``"service"`` (HTTP only).
    meaning : str
        One line for people.
    """

    code: str
    http_statuses: tuple[int, ...]
    exit_status: int | None
    source: str
    meaning: str


def _e(code: str, http: tuple[int, ...], exit_status: int | None, source: str, meaning: str
       ) -> ErrorCodeInfo:
    return ErrorCodeInfo(code, http, exit_status, source, meaning)


_IN, _USE = EXIT_INPUT_ERROR, EXIT_USAGE

#: Every error code, in the order of the README's table.
ERROR_CODES: tuple[ErrorCodeInfo, ...] = (
    _e("empty_body", (400,), _IN, "core", "no image bytes: an empty file, upload or body"),
    _e("unsupported_media_type", (415,), _IN, "core",
       "not an image, or a format that is not read"),
    _e("undecodable_image", (422,), _IN, "core", "a known format, but truncated or corrupt"),
    _e("invalid_image", (422,), _IN, "core", "an array of the wrong shape, empty, or not finite"),
    _e("image_too_large", (413,), _IN, "core", "more pixels than the cap (decompression bomb)"),
    _e("payload_too_large", (413,), _IN, "core", "more bytes than the cap"),
    _e("undecodable_video", (422,), _IN, "core",
       "a known video container, but truncated, broken or not decodable"),
    _e("video_too_long", (413,), _IN, "core", "a video longer (seconds or frames) than the cap"),
    _e("invalid_config", (), _USE, "core", "a bad config file, detector setting or policy"),
    _e("invalid_spec", (), _USE, "core", "a barcode spec breaks a validation rule"),
    _e("firmware_error", (), _USE, "core", "a sequence cannot be compiled or read back"),
    _e("not_found", (404,), _IN, "core", "no such input file (HTTP: no such route)"),
    _e("read_error", (), _IN, "core",
       "an input file that cannot be read (permissions, a loop of links, an I/O error)"),
    _e("unsafe_member_name", (), _IN, "scan",
       "an archive member with an absolute or escaping name"),
    _e("link_member", (), _IN, "scan", "an archive member that is a link"),
    _e("special_member", (), _IN, "core", "a device, fifo or other non-regular file or member"),
    _e("encrypted_member", (), _IN, "scan", "an encrypted archive member"),
    _e("corrupt_member", (), _IN, "scan", "an archive member that cannot be read"),
    _e("unreadable_archive", (), _IN, "scan", "an archive that cannot be opened"),
    _e("truncated_archive", (), _IN, "scan", "an archive cut short"),
    _e("worker_crashed", (), _IN, "scan", "the process screening an input died"),
    _e("internal_error", (500,), _IN, "core", "a bug; the service logs it with the request id"),
    _e("invalid_request", (422, 400), None, "service",
       "a request without the expected fields, or a bad Content-Length"),
    _e("invalid_multipart", (400,), None, "service", "broken multipart framing"),
    _e("too_many_files", (422,), None, "service", "more files than max_batch_files"),
    _e("unauthorized", (401,), None, "service", "missing or wrong bearer token"),
    _e("body_timeout", (408,), None, "service", "the body did not arrive within body_timeout_s"),
    _e("overloaded", (503,), None, "service", "too much work in flight; retry after Retry-After"),
    _e("not_ready", (503,), None, "service", "the detector is still warming up"),
    _e("timeout", (504,), None, "service",
       "the detection exceeded detect_timeout_s (and was ended)"),
    _e("client_disconnected", (499,), None, "service",
       "the client left (logged, never sent; its detection is ended)"),
    _e("bad_request", (400,), None, "service", "a malformed HTTP request"),
    _e("forbidden", (403,), None, "service", "refused"),
    _e("method_not_allowed", (405,), None, "service", "wrong HTTP method for the route"),
    _e("not_acceptable", (406,), None, "service", "an Accept header the route cannot satisfy"),
    _e("too_many_requests", (429,), None, "service", "rate limited"),
    _e("unavailable", (503,), None, "service", "the service is unavailable"),
    _e("http_error", (), None, "service", "any other HTTP error of the framework"),
)

_BY_CODE = {info.code: info for info in ERROR_CODES}


def error_code(code: str) -> ErrorCodeInfo:
    """The table's entry for ``code``.

    Raises
    ------
    KeyError
        When ``code`` is not in `ERROR_CODES` (a test keeps every raised code in it).

    Examples
    --------
    >>> error_code("empty_body").http_statuses
    (400,)
    """
    return _BY_CODE[code]


def exit_status_table_markdown() -> str:
    """The README's exit-status table: each status, its meaning and the error codes leading
    to it (from `ERROR_CODES`)."""
    rows = ["| exit status | meaning | error codes |", "|---|---|---|"]
    for status, meaning in EXIT_MEANINGS.items():
        codes = ", ".join(f"`{e.code}`" for e in ERROR_CODES if e.exit_status == status)
        rows.append(f"| {status} | {meaning} | {codes or '-'} |")
    return "\n".join(rows) + "\n"


def error_code_table_markdown() -> str:
    """`ERROR_CODES` as the Markdown table of the README (code, HTTP, exit status, meaning)."""
    rows = ["| code | HTTP status | CLI exit status | meaning |", "|---|---|---|---|"]
    for e in ERROR_CODES:
        http = ", ".join(map(str, e.http_statuses)) or "-"
        exit_status = "-" if e.exit_status is None else str(e.exit_status)
        rows.append(f"| `{e.code}` | {http} | {exit_status} | {e.meaning} |")
    return "\n".join(rows) + "\n"


def classify(exc: BaseException) -> tuple[str, str]:
    """The stable code and the message of any exception, as every interface reports it.

    A `LishieldError` keeps its own ``code``; an `OSError` that escaped a reader is
    ``not_found`` or ``read_error`` (as `input_file_error` would have typed it); anything
    else is a bug, ``internal_error``, with the exception's type in the message.

    Parameters
    ----------
    exc : BaseException
        What a detection raised.

    Returns
    -------
    code : str
        An entry of `ERROR_CODES`.
    message : str
        For people.

    Examples
    --------
    >>> classify(EmptyImageError("empty input: no image bytes"))
    ('empty_body', 'empty input: no image bytes')
    >>> classify(KeyError("x"))
    ('internal_error', "internal error: KeyError: 'x'")
    """
    if isinstance(exc, LishieldError):
        return exc.code, str(exc)
    if isinstance(exc, OSError):
        typed = input_file_error(exc, str(exc.filename) if exc.filename else "input")
        return typed.code, str(typed)
    return "internal_error", f"internal error: {type(exc).__name__}: {exc}"
