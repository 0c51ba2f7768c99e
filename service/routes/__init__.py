"""HTTP routes: screening (``/v1/screen``), read-only config (``/v1/policies``), operations."""

from service.routes import ops, policies, screen

__all__ = ["ops", "policies", "screen"]
