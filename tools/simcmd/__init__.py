"""Subcommands of placecell-sim."""

from __future__ import annotations

from pathlib import Path

from daemon import config as config_mod
from daemon.config import PlacecellConfig

DEFAULT_CONFIG = Path("config/placecell.toml")


def load_config(path: str | None) -> PlacecellConfig:
    """``--config``'s file; without one config/placecell.toml where it is (run from the
    repository), else the built-in defaults, as placecelld chooses."""
    if not path and DEFAULT_CONFIG.is_file():
        path = str(DEFAULT_CONFIG)
    return config_mod.load(path or None)
