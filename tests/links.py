"""Pseudo-terminal pairs made with socat: the serial cable (and slcan CAN adapters) of tests."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from tests.daemon_harness import REPO


class PtyPair:
    """``socat`` linking two pseudo-terminals at stable paths (``link=``), so a test can
    kill the 'cable' and plug it back in at the same paths."""

    def __init__(self, a: Path, b: Path) -> None:
        if shutil.which("socat") is None:
            raise RuntimeError("socat is not installed (make test installs it)")
        self.a, self.b = a, b
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> PtyPair:
        self.proc = subprocess.Popen(
            ["socat", f"pty,raw,echo=0,link={self.a}", f"pty,raw,echo=0,link={self.b}"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        end = time.monotonic() + 5
        while not (self.a.exists() and self.b.exists()):
            if time.monotonic() > end:
                raise RuntimeError("socat did not create the pseudo-terminals")
            time.sleep(0.01)
        return self

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            self.proc.wait(5)
        self.proc = None
        end = time.monotonic() + 2
        while (self.a.exists() or self.b.exists()) and time.monotonic() < end:
            time.sleep(0.01)


@contextlib.contextmanager
def pty_pair(tmp: Path, name: str = "xr") -> Iterator[PtyPair]:
    pair = PtyPair(tmp / f"{name}-robot", tmp / f"{name}-daemon").start()
    try:
        yield pair
    finally:
        pair.stop()


def emulator(args: list[str]) -> subprocess.Popen[str]:
    """The emulator as its own process (the console script, run from the repo)."""
    return subprocess.Popen([sys.executable, "-m", "tools.xr4000_emulator", *args], cwd=REPO,
                            env={**os.environ}, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


def stop(proc: subprocess.Popen[str], timeout: float = 10.0) -> str:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return out or ""
