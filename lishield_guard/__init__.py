"""lishield-guard: find LiShield frequency-ratio barcodes (LED flicker stripes) in photos.

The public names below are imported on first use (PEP 562), so that ``import lishield_guard``
and the command line start without loading numpy, scipy, OpenCV or the detector until a
command needs them: ``lishield_guard.detect`` imports the detector, ``lishield_guard.Verdict``
only the verdict module.
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING, Any

#: public name -> module that defines it
_LAZY = {
    "CameraModel": "lishield_guard.camera",
    "cpr_to_hz": "lishield_guard.camera",
    "hz_to_cpr": "lishield_guard.camera",
    "AppConfig": "lishield_guard.config",
    "DetectorConfig": "lishield_guard.config",
    "Limits": "lishield_guard.config",
    "Policy": "lishield_guard.config",
    "default_config": "lishield_guard.config",
    "dump_config": "lishield_guard.config",
    "load_config": "lishield_guard.config",
    "decode": "lishield_guard.decode",
    "validate_image": "lishield_guard.decode",
    "detect": "lishield_guard.detector",
    "ConfigError": "lishield_guard.errors",
    "CorruptImageError": "lishield_guard.errors",
    "EmptyImageError": "lishield_guard.errors",
    "FirmwareError": "lishield_guard.errors",
    "ImageDecodeError": "lishield_guard.errors",
    "ImageTooLargeError": "lishield_guard.errors",
    "InputFileError": "lishield_guard.errors",
    "InputNotFoundError": "lishield_guard.errors",
    "InvalidImageError": "lishield_guard.errors",
    "LishieldError": "lishield_guard.errors",
    "PayloadTooLargeError": "lishield_guard.errors",
    "SpecError": "lishield_guard.errors",
    "SpecialFileError": "lishield_guard.errors",
    "UnsupportedImageError": "lishield_guard.errors",
    "PRESETS": "lishield_guard.spec",
    "BarcodeSpec": "lishield_guard.spec",
    "check_spec": "lishield_guard.spec",
    "get_preset": "lishield_guard.spec",
    "Verdict": "lishield_guard.verdict",
}

__all__ = [
    "AppConfig",
    "BarcodeSpec",
    "CameraModel",
    "ConfigError",
    "CorruptImageError",
    "DetectorConfig",
    "EmptyImageError",
    "FirmwareError",
    "ImageDecodeError",
    "ImageTooLargeError",
    "InputFileError",
    "InputNotFoundError",
    "InvalidImageError",
    "Limits",
    "LishieldError",
    "PRESETS",
    "PayloadTooLargeError",
    "Policy",
    "SpecError",
    "SpecialFileError",
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


def __getattr__(name: str) -> Any:
    """Import a public name's module on first use and cache the name here."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'lishield_guard' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


class _Package(types.ModuleType):
    """The package keeps ``decode`` the function: importing the submodule of the same name
    would otherwise rebind the package attribute to the module (an eager ``from
    lishield_guard.decode import decode`` used to rebind it back)."""

    def __setattr__(self, name: str, value: Any) -> None:
        if isinstance(value, types.ModuleType) and _LAZY.get(name) == value.__name__:
            value = getattr(value, name)
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package


if TYPE_CHECKING:  # for type checkers and IDEs: the names as if imported eagerly
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
        EmptyImageError,
        FirmwareError,
        ImageDecodeError,
        ImageTooLargeError,
        InputFileError,
        InputNotFoundError,
        InvalidImageError,
        LishieldError,
        PayloadTooLargeError,
        SpecError,
        SpecialFileError,
        UnsupportedImageError,
    )
    from lishield_guard.spec import PRESETS, BarcodeSpec, check_spec, get_preset
    from lishield_guard.verdict import Verdict
