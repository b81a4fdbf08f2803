"""The daemon mapping for half an hour (docs/design.md §13): ``placecell-bench --only soak``.

Not among the groups a plain ``placecell-bench`` runs: it takes ``PLACECELL_SOAK_MINUTES``
(30 by default) and a minute more. The real daemon on its simulated robot driving the
default demo tour (config/placecell.toml's ``[sim]``), mapping mode with acquisition on,
starts on an empty map and runs that long; then a fresh daemon opens the map it made, on
the same simulated robot (whose renderer shares the process in both runs), in localisation
mode, and runs FRESH_S. One run, whatever ``repeats`` says:

- ``soak_minutes``, ``soak_places``: how long it mapped, how many places it learned;
- ``soak_rss_mb_end``: the mapping daemon's resident memory at its last belief;
- ``soak_rss_mb_fresh``: the fresh daemon's at its last belief;
- ``soak_rss_growth_mb``: the first less the second — what mapping holds beyond what the
  map needs (issue 36: within 50 MB).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from pathlib import Path

from daemon.store.sqlite_store import MapStore
from tools.bench.daemon import WAIT_S, _daemon, _wait

FRESH_S = 60.0  # the fresh daemon runs this long before its memory is read


def _minutes() -> float:
    raw = os.environ.get("PLACECELL_SOAK_MINUTES", "30")
    try:
        minutes = float(raw)
    except ValueError:
        raise SystemExit(f"PLACECELL_SOAK_MINUTES={raw!r} is not a number of minutes") from None
    if not 0 < minutes <= 24 * 60:
        raise SystemExit(f"PLACECELL_SOAK_MINUTES={raw!r}: give 0 < minutes <= 1440")
    return minutes


def _run_for(run_dir: Path, overrides: dict[str, object], seconds: float) -> float:
    """The daemon on ``overrides`` for ``seconds`` after its first belief: RSS at the last."""
    with _daemon(run_dir, overrides) as (_, seen, _session):
        _wait(seen, lambda s: len(s.beliefs) > 0, "published a belief", run_dir)
        first = seen.arrivals[0]
        end = first + seconds
        with seen.changed:
            seen.changed.wait_for(lambda: seen.arrivals[-1] >= end,
                                  timeout=max(0.0, end - time.monotonic()) + WAIT_S)
            if seen.arrivals[-1] < end:
                raise RuntimeError(f"the daemon stopped publishing beliefs after "
                                   f"{seen.arrivals[-1] - first:.0f} s of {seconds:.0f}")
            return seen.usage_at[-1][2]


def run(repeats: int) -> dict[str, float]:
    del repeats  # one run: it is half an hour
    minutes = _minutes()
    with tempfile.TemporaryDirectory() as tmp:
        mapping_dir, fresh_dir = Path(tmp) / "mapping", Path(tmp) / "fresh"
        mapping_dir.mkdir()
        fresh_dir.mkdir()
        map_path = mapping_dir / "map.db"
        rss_end = _run_for(mapping_dir, {
            "map": {"path": str(map_path)},
            "mapping": {"mode": "mapping", "acquisition": {"enabled": True}}}, minutes * 60)
        with MapStore.open(map_path, None, readonly=True) as store:
            places = len(store.load())
        shutil.copyfile(map_path, fresh_dir / "map.db")
        rss_fresh = _run_for(fresh_dir, {
            "map": {"path": str(fresh_dir / "map.db")},
            "mapping": {"mode": "localisation"}}, FRESH_S)
    return {"soak_minutes": minutes, "soak_places": float(places),
            "soak_rss_mb_end": round(rss_end, 1), "soak_rss_mb_fresh": round(rss_fresh, 1),
            "soak_rss_growth_mb": round(rss_end - rss_fresh, 1)}
