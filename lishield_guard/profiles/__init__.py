"""The detector profiles behind one registry: each name maps to the module that runs it.

A profile module decides one decoded image from start to end and explains its verdict:

=======================  ====================================================================
``NAME``                 its registry name (`name_of`)
``decode(source, cfg)``  the image decoded as the profile analyses it (planes, scale)
``measure``              decoded pixels -> the profile's typed record (what it decides on)
``decide``               record -> `Verdict`, whose ``evidence`` is the profile's typed evidence
                         (its reason, the spec it names, its figure and caption)
``required(cfg)``        evidence units a protected verdict needs (``Verdict.required``)
=======================  ====================================================================

`lishield_guard.profiles.detect` runs them. The CLI (``--profile``), the service, ``scan``,
calibration and the video screen name profiles through this table only: adding a profile is
one name and one entry here, and its own module. The config validates names against it, so
this module imports nothing of the package; a profile's module is imported on first use.
"""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = ["CASCADE", "DEFAULT", "LEARNED", "NAMES", "PAPER", "REGISTRY", "get", "name_of", "of"]

LEARNED = "default"  # the learned decision: fixed cost per image
CASCADE = "cascade"  # the pattern search it replaced
PAPER = "paper"  # the paper's Algorithm 1, as published
#: name -> module of every detector profile, the default first.
REGISTRY: dict[str, str] = {
    LEARNED: "lishield_guard.profiles.learned",
    CASCADE: "lishield_guard.profiles.cascade",
    PAPER: "lishield_guard.profiles.paper",
}
NAMES: tuple[str, ...] = tuple(REGISTRY)
DEFAULT: str = NAMES[0]


def get(name: str) -> ModuleType:
    """The module of profile ``name``.

    Raises
    ------
    ConfigError
        When ``name`` is not in `REGISTRY`.
    """
    if name not in REGISTRY:
        from lishield_guard.errors import ConfigError

        raise ConfigError(f"profile must be one of {', '.join(map(repr, NAMES))}, got "
                          f"{name!r}")
    return importlib.import_module(REGISTRY[name])


def name_of(module: str) -> str:
    """The registry name of the profile implemented by ``module`` (its ``__name__``)."""
    return next(name for name, path in REGISTRY.items() if path == module)


def of(config) -> ModuleType:
    """The module of the profile an `AppConfig` (or a `DetectorConfig`) selects."""
    det = getattr(config, "detector", config)
    return get(det.profile)

