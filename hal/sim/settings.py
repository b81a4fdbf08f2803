"""Settings shared by the `sim` camera and base backends (one simulated robot)."""

from __future__ import annotations

from dataclasses import dataclass

from kernel.settings import setting


@dataclass(frozen=True)
class SimSettings:
    world: str = setting(
        "generate:office:1",
        doc="world TOML path, or generate:<kind>:<seed> for a generated world",
    )
    scenario: str = setting("config/scenarios/demo-tour.toml",
                            doc="scenario TOML path (relative to the working directory); "
                            "empty: the robot stands still")
    seed: int = setting(1, ge=0, doc="seed of the simulator's noise and drift")
    realtime: bool = setting(
        True, doc="run on the wall clock (daemon) or in lock-step with frame reads (evaluation)"
    )
    truth_out: str = setting(
        "", doc="append the true pose at every simulation step to this JSON-lines file (for "
        "tests and evaluation: the method never sees it); empty: not written")
    mount_error_x_m: float = setting(0.0, ge=-1.0, le=1.0, doc="the simulated camera sits "
                                     "this far ahead of where [camera] mount says")
    mount_error_y_m: float = setting(0.0, ge=-1.0, le=1.0, doc="...and this far left")
    mount_error_yaw_rad: float = setting(0.0, ge=-3.141592653589793, le=3.141592653589793,
                                         doc="...and turned this much")
    start_pose: list[float] = setting(
        [0.0, 0.0, 0.0], doc="x, y, yaw in the world frame; used when no scenario is set"
    )

    def __post_init__(self) -> None:
        if len(self.start_pose) != 3:
            raise ValueError("start_pose must be [x, y, yaw]")
