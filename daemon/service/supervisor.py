"""The supervised loop: one thread per component, each restarted with backoff on failure.

A component is a device (camera, base) or the processing step. Its thread runs
``setup()`` then ``step()`` until stopped; any exception is logged with what failed and why,
reported as an event, the component is torn down, and after a backoff (doubling from
``restart_backoff_initial_s`` up to ``restart_backoff_max_s``) it is set up again. The
same failure again is reported as a summary once per ``fault_summary_s``. The daemon
itself never exits because a device failed.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable
from typing import Any, Protocol

from daemon.service.health import ComponentHealth

log = logging.getLogger(__name__)

EventSink = Callable[..., None]


class Component(Protocol):
    name: str

    def setup(self) -> None:
        """Open what the component needs (a device); raises on failure."""

    def step(self) -> None:
        """One bounded iteration (waits at most about a second); raises on failure."""

    def teardown(self) -> None:
        """Release everything; must not raise and must be safe to call twice."""


@dataclasses.dataclass(frozen=True)
class FaultRun:
    """A run of the same failure of one component: what, since when, how often, and when
    it was last reported."""

    error: str
    first_ns: int
    count: int
    reported_ns: int


def next_fault(run: FaultRun | None, error: str, now_ns: int, summary_every_s: float
               ) -> tuple[FaultRun, bool]:
    """The run after one more failure, and whether to report it now: a new failure (or
    another error than the run's) at once; the same one again only as a summary, once per
    ``summary_every_s`` (a camera unplugged all night is two lines a minute, not two a
    second that push everything else out of the log and the event history)."""
    if run is None or run.error != error:
        return FaultRun(error, now_ns, 1, now_ns), True
    due = now_ns - run.reported_ns >= summary_every_s * 1e9
    return dataclasses.replace(run, count=run.count + 1,
                               reported_ns=now_ns if due else run.reported_ns), due


class Supervisor:
    def __init__(self, backoff_initial_s: float, backoff_max_s: float,
                 on_event: EventSink | None = None, fault_summary_s: float = 60.0) -> None:
        self._backoff_initial_s = backoff_initial_s
        self._backoff_max_s = backoff_max_s
        self._fault_summary_s = fault_summary_s
        self._on_event = on_event or (lambda kind, **fields: None)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.health: dict[str, ComponentHealth] = {}
        self._components: dict[str, Component] = {}

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def add(self, component: Component) -> ComponentHealth:
        health = ComponentHealth(component.name)
        self.health[component.name] = health
        self._components[component.name] = component
        return health

    def start(self) -> None:
        for name, component in self._components.items():
            t = threading.Thread(target=self._run, args=(component, self.health[name]),
                                 name=f"placecell-{name}", daemon=True)
            self._threads.append(t)
            t.start()

    def all_running(self) -> bool:
        return all(h.state == "running" for h in self.health.values())

    def threads_alive(self, max_silence_s: float) -> bool:
        """True while every component thread is alive and has beaten recently: the loop is
        healthy (devices may still be in backoff; that is reported, not fatal)."""
        now = time.monotonic_ns()
        return all(t.is_alive() for t in self._threads) and all(
            now - h.heartbeat_ns < max_silence_s * 1e9 for h in self.health.values()
        )

    def stop(self, timeout_s: float) -> bool:
        """Ask every component to stop and wait up to ``timeout_s`` in total."""
        self._stop.set()
        deadline = time.monotonic() + timeout_s
        for t in self._threads:
            t.join(max(0.0, deadline - time.monotonic()))
        stuck = [t.name for t in self._threads if t.is_alive()]
        if stuck:
            log.warning("components still stopping after %.1f s: %s", timeout_s, stuck)
        return not stuck

    def _run(self, component: Component, health: ComponentHealth) -> None:
        backoff = self._backoff_initial_s
        faults: FaultRun | None = None
        while not self._stop.is_set():
            try:
                health.state = "starting"
                health.beat()
                component.setup()
                while not self._stop.is_set():
                    component.step()
                    health.beat()
                    if health.state != "running":
                        # Running means delivering: the first step after set-up worked.
                        health.state = "running"
                        backoff = self._backoff_initial_s
                        faults = None
                        if health.last_error is not None:
                            log.info("%s recovered after %d restart(s)", component.name,
                                     health.restarts)
                            self._on_event("device_recovered", component=component.name,
                                           restarts=health.restarts)
            except Exception as e:  # noqa: BLE001 - the supervisor's whole job
                reason = f"{type(e).__name__}: {e}"
                now = time.monotonic_ns()
                health.state = "backoff"
                health.last_error = reason
                health.last_error_mono_ns = now
                health.restarts += 1
                faults, report = next_fault(faults, reason, now, self._fault_summary_s)
                since_s = (now - faults.first_ns) / 1e9
                if not report:
                    log.debug("%s failed again: %s", component.name, reason)
                elif faults.count == 1:
                    log.error("%s failed: %s; restarting in %.2f s", component.name, reason,
                              backoff)
                else:
                    log.error("%s still failing: %d times in %.0f s, %s; retrying every "
                              "%.2f s", component.name, faults.count, since_s, reason, backoff)
                if report:
                    self._on_event("device_fault", component=component.name, error=reason,
                                   retry_in_s=backoff, repeats=faults.count,
                                   failing_for_s=round(since_s, 3))
                _teardown(component)
                self._wait(backoff, health)
                backoff = min(backoff * 2.0, self._backoff_max_s)
                continue
        _teardown(component)
        health.state = "stopped"

    def _wait(self, seconds: float, health: ComponentHealth) -> None:
        end = time.monotonic() + seconds
        while not self._stop.is_set():
            left = end - time.monotonic()
            if left <= 0:
                return
            self._stop.wait(min(left, 0.2))
            health.beat()


def _teardown(component: Component) -> None:
    try:
        component.teardown()
    except Exception as e:  # noqa: BLE001 - teardown must never take the thread down
        log.warning("%s teardown failed: %s", component.name, e)


def describe(health: dict[str, ComponentHealth], now_ns: int) -> dict[str, Any]:
    return {name: h.as_dict(now_ns) for name, h in health.items()}
