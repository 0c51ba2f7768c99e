"""lishield-guard: find LiShield frequency-ratio barcodes (LED flicker stripes) in photos."""

from lishield_guard.camera import CameraModel, cpr_to_hz, hz_to_cpr
from lishield_guard.config import (
    AppConfig,
    DetectorConfig,
    Limits,
    Policy,
    default_config,
    dump_config,
    load_config,
)
from lishield_guard.decode import decode, validate_image
from lishield_guard.detector import detect
from lishield_guard.errors import (
    ConfigError,
    CorruptImageError,
    FirmwareError,
    ImageDecodeError,
    ImageTooLargeError,
    InvalidImageError,
    LishieldError,
    PayloadTooLargeError,
    SpecError,
    UnsupportedImageError,
)
from lishield_guard.spec import PRESETS, BarcodeSpec, check_spec, get_preset
from lishield_guard.verdict import Verdict

__all__ = [
    "PRESETS",
    "AppConfig",
    "BarcodeSpec",
    "CameraModel",
    "ConfigError",
    "CorruptImageError",
    "DetectorConfig",
    "FirmwareError",
    "ImageDecodeError",
    "ImageTooLargeError",
    "InvalidImageError",
    "Limits",
    "LishieldError",
    "PayloadTooLargeError",
    "Policy",
    "SpecError",
    "UnsupportedImageError",
    "Verdict",
    "check_spec",
    "cpr_to_hz",
    "decode",
    "default_config",
    "detect",
    "dump_config",
    "get_preset",
    "hz_to_cpr",
    "load_config",
    "validate_image",
]

__version__ = "0.1.0"
