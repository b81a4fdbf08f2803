"""A base re-opened by the supervisor breaks the mapper's odometry chain only when its
odometry may start from anywhere (design §6): the simulated robot lives on in the process,
so re-opening it must not cost the transition between two places learned across it."""

from __future__ import annotations

from typing import Any

from daemon.service.components import base_component
from daemon.service.health import ComponentHealth
from hal.base.base import BaseInfo
from hal.registry import HalContext, create_base
from tests.sim_helpers import lockstep_config


class _PowerCycledBase:
    """A base whose odometry restarts when its link is opened again (an XR4000 that was
    power-cycled while the cable was out)."""

    info = BaseInfo("stub", "power-cycled base", True, 50.0)

    def open(self) -> None:
        pass

    def close(self) -> None:
        pass


def _times_told(make_base: Any, opens: int) -> int:
    told: list[int] = []
    health = ComponentHealth("base")
    component = base_component(make_base, 0.5, lambda samples: None, lambda: health, [],
                               on_open=lambda: told.append(1))
    for _ in range(opens):  # the supervisor: set up, fail, tear down, set up again
        component.setup()
        component.teardown()
    return len(told)


def test_a_reopened_sim_base_keeps_its_odometry_frame() -> None:
    config = lockstep_config()
    ctx = HalContext(config)
    assert create_base(config.base, ctx).info.odometry_kept_on_reopen
    assert _times_told(lambda: create_base(config.base, ctx), 3) == 0


def test_a_base_whose_odometry_restarts_is_reported_on_every_reopen_not_the_first() -> None:
    assert _times_told(_PowerCycledBase, 1) == 0
    assert _times_told(_PowerCycledBase, 3) == 2
