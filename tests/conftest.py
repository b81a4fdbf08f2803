"""Fixtures shared by the end-to-end tests."""

from __future__ import annotations

# One BLAS thread, before numpy loads OpenBLAS (kernel/threads.py): the lock-step tests
# drive the daemon's Localiser as the daemon runs it, and two workers with OpenBLAS's
# spinning threads each would fight over two cores.
from kernel.threads import one_blas_thread

one_blas_thread()

import contextlib  # noqa: E402 - after the thread setting above
import shutil  # noqa: E402
from collections.abc import Callable, Iterator  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

from kernel.se2 import SE2  # noqa: E402
from tools.eval.lockstep import Run, lockstep_config  # noqa: E402

OfficeMap = Callable[[Path], dict[str, SE2]]

# `make test` runs the tests on two workers (pytest-xdist, ``--dist loadgroup``). The
# modules that hold a daemon, an emulator or a load to wall-clock limits (a link back
# within 2 s, an abort within 0.5 s, ten queries a second for a minute) are in the
# xdist group "realtime" (their ``pytestmark``): one worker runs them one after the
# other, never two of them at once on a 2-core machine.


@pytest.fixture(scope="session")
def office_map(tmp_path_factory: pytest.TempPathFactory) -> OfficeMap:
    """Three places "a", "b", "c" 1.5 m apart along the office corridor from (3, 10),
    learned once per session by the daemon's own Turn Back and Look loop on the lock-step
    simulator. Call it with a path: a fresh copy of the map file is put there, and the
    places' true reference poses (for the evaluator's side only) are returned."""
    master = tmp_path_factory.mktemp("office-map") / "map.db"
    with Run(lockstep_config(1, start_pose=(3.0, 10.0, 0.0)), map_path=master) as run:
        labels = {}
        for i, label in enumerate("abc"):
            if i:
                for _ in run.drive(1.5, 0.0, 0.0, 0.3):
                    pass
            labels[label] = run.learn(label).id
        refs = {label: run.references[pid] for label, pid in labels.items()}

    def copy(path: Path) -> dict[str, SE2]:
        shutil.copyfile(master, path)
        return dict(refs)

    return copy


@contextlib.contextmanager
def run_at(tmp_path: Path, office_map: OfficeMap, label: str
           ) -> Iterator[tuple[Run, dict[str, SE2]]]:
    """A lock-step run on a fresh copy of the office map (``office_map``), the robot at
    place ``label``'s reference; with the places' true reference poses by label."""
    refs = office_map(tmp_path / "map.db")
    ref = refs[label]
    with Run(lockstep_config(1, start_pose=(ref.x, ref.y, ref.yaw)),
             map_path=tmp_path / "map.db") as run:
        yield run, refs
