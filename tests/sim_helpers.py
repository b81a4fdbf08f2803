"""Shared helpers for simulator tests: configurations in lock-step mode."""

from __future__ import annotations

import dataclasses
from typing import Any

from daemon.config import PlacecellConfig, load


def lockstep_config(**sim: Any) -> PlacecellConfig:
    """The built-in configuration with the simulator in lock-step mode, the robot still
    (no scenario) unless one is given."""
    c = load(None)
    return dataclasses.replace(c, sim=dataclasses.replace(
        c.sim, **{"realtime": False, "scenario": "", **sim}))


def with_sections(config: PlacecellConfig, **sections: dict[str, Any]) -> PlacecellConfig:
    """Replace fields of named sections, e.g. with_sections(c, camera_sim={"rate_hz": 2})."""
    for name, fields in sections.items():
        path = name.split("_", 1) if name in ("camera_sim", "base_sim") else [name]
        if len(path) == 2:
            outer = getattr(config, path[0])
            inner = dataclasses.replace(getattr(outer, path[1]), **fields)
            config = dataclasses.replace(config, **{path[0]: dataclasses.replace(
                outer, **{path[1]: inner})})
        else:
            config = dataclasses.replace(config, **{name: dataclasses.replace(
                getattr(config, name), **fields)})
    return config
