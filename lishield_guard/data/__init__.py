"""Shipped data files: the default TOML config."""
