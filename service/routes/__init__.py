"""HTTP routes: screening (``/v1/screen``), read-only config (``/v1/policies``), operations,
and the reviewer's page and figure (``/review``, ``/v1/review``, ``/v1/screen/plot``)."""

from service.routes import ops, policies, review, screen

__all__ = ["ops", "policies", "review", "screen"]
