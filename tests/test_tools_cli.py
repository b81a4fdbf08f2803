"""The offline tools run through the same code as the daemon and print what they say."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

from tests.daemon_harness import REPO, venv_bin


def test_bench_reports_named_figures() -> None:
    out = subprocess.run([venv_bin("placecell-bench"), "--json", "--only", "sim",
                          "--repeats", "1"], cwd=REPO, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    figures = json.loads(out.stdout)["figures"]
    assert set(figures) == {"render_fps", "unwarp_ms"}
    assert figures["render_fps"] > 0 and figures["unwarp_ms"] > 0


def test_world_and_render_commands(tmp_path: Path) -> None:
    world = tmp_path / "w.toml"
    out = subprocess.run([venv_bin("placecell-sim"), "world", "--kind", "open-room", "--seed",
                          "2", "--out", str(world)], cwd=REPO, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0 and world.exists(), out.stderr
    pics = tmp_path / "pics"
    out = subprocess.run([venv_bin("placecell-sim"), "render", "--world", str(world),
                          "--pose", "3.5,5,0.3", "--out", str(pics)], cwd=REPO,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    import cv2

    plan, donut, pano = (cv2.imread(str(pics / n)) for n in
                         ("plan.png", "donut.png", "panorama.png"))
    assert plan is not None and plan.std() > 10
    assert donut.shape == (480, 640, 3) and pano.shape == (120, 752, 3)
    bad = subprocess.run([venv_bin("placecell-sim"), "render", "--world", str(world),
                          "--pose", "nonsense", "--out", str(pics)], cwd=REPO,
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "--pose" in bad.stderr


def test_process_usage_counts_cpu_time_and_memory() -> None:
    """What the daemon benchmark reads of a process (tools/daemon_process.usage)."""
    import os
    import time

    from tools.daemon_process import usage

    before = usage(os.getpid())
    spin_until = time.process_time() + 0.2
    while time.process_time() < spin_until:
        pass
    after = usage(os.getpid())
    assert after.cpu_s - before.cpu_s >= 0.15
    assert 10 < after.rss_mb < 10_000
