"""The cascade profile (the pattern search) for the tests of its stages: the shipped config with
``profile = "cascade"``, and `detect` under it."""

from __future__ import annotations

from functools import cache

from lishield_guard import AppConfig, default_config
from lishield_guard import detect as _detect


@cache
def cascade_config() -> AppConfig:
    """The shipped config, profile cascade."""
    base = default_config()
    return AppConfig(detector=base.detector.replace(profile="cascade"), limits=base.limits,
                     policies=base.policies, source=base.source)


def detect_cascade(source, config=None):
    """`lishield_guard.detect` with the cascade profile (a bare DetectorConfig or AppConfig
    given is switched to it)."""
    if config is None:
        return _detect(source, cascade_config())
    if isinstance(config, AppConfig):
        return _detect(source, AppConfig(detector=config.detector.replace(profile="cascade"),
                                         limits=config.limits, policies=config.policies,
                                         source=config.source))
    return _detect(source, config.replace(profile="cascade"))
