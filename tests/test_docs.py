"""The docs' commands run: every ``placecellctl`` and ``placecelld`` command of
docs/troubleshooting.md, against a running daemon on a map of three places (the page's
map path and configuration swapped for the test's), answers with exit code 0 and no
traceback; and the docs cite only what the repository has."""

from __future__ import annotations

import re
import shlex
import subprocess
from pathlib import Path

from tests.conftest import OfficeMap
from tests.daemon_harness import REPO, running_daemon, venv_bin, wait_for, write_config

PAGE = REPO / "docs" / "troubleshooting.md"


def _commands(page: Path) -> list[list[str]]:
    blocks = re.findall(r"```sh\n(.*?)```", page.read_text(), flags=re.S)
    lines = [line.strip() for block in blocks for line in block.splitlines()]
    return [shlex.split(line) for line in lines
            if line.startswith(("placecellctl ", "placecelld "))]


def test_every_troubleshooting_command_runs(tmp_path: Path, office_map: OfficeMap) -> None:
    commands = _commands(PAGE)
    assert len(commands) >= 12, commands
    office_map(tmp_path / "map.db")
    config, _ = write_config(tmp_path, {"map": {"path": str(tmp_path / "map.db")}})
    with running_daemon(config):
        def up() -> bool:
            return subprocess.run([venv_bin("placecellctl"), "--config", str(config), "status"],
                                  capture_output=True, timeout=60).returncode == 0

        assert wait_for(up, 60, 0.2)
        for argv in commands:
            argv = [a.replace("var/placecell.db", str(tmp_path / "map.db"))
                    .replace("/tmp/map.png", str(tmp_path / "map.png")) for a in argv]
            done = subprocess.run([venv_bin(argv[0]), "--config", str(config), *argv[1:]],
                                  cwd=REPO, capture_output=True, text=True, timeout=120)
            assert done.returncode == 0 and "Traceback" not in done.stderr, (
                argv, done.returncode, done.stdout[-500:], done.stderr[-1500:])
    assert (tmp_path / "map.png").stat().st_size > 1000


def test_docs_cite_no_document_outside_the_repository() -> None:
    """No 'SPEC §' (a document that is not here) and no design section docs/design.md
    does not have, in code, configuration or docs."""
    design = (REPO / "docs" / "design.md").read_text()
    sections = {int(n) for n in re.findall(r"^## (\d+)\.", design, flags=re.M)}
    tracked = subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True,
                             check=True).stdout.split()
    bad = []
    for name in tracked:
        if not name.endswith((".py", ".md", ".toml", ".json", ".json5", ".service")) \
                or name == "tests/test_docs.py":  # this file names what it looks for
            continue
        text = (REPO / name).read_text(errors="replace")
        if "SPEC §" in text or "shared/design" in text:
            bad.append(f"{name}: cites a document outside the repository")
        for n in re.findall(r"design(?:\.md)? §(\d+)", text):
            if int(n) not in sections:
                bad.append(f"{name}: design §{n}")
    assert not bad, bad
