"""The backend registry: names map to lazily imported classes; failures say what to do."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from hal import registry
from kernel.errors import BackendUnavailableError, UnknownBackendError


def test_unknown_backend_lists_the_known_ones() -> None:
    with pytest.raises(UnknownBackendError, match=r"unknown camera backend 'webcam' \(known: "):
        registry.load_backend("camera", "webcam")
    with pytest.raises(UnknownBackendError, match="xr4000-serial"):
        registry.load_backend("base", "nomad")


def test_unavailable_backend_names_the_missing_package(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # A backend module whose optional dependency is not installed.
    (tmp_path / "fake_backend_mod.py").write_text(
        "import placecell_missing_dependency_xyz\nclass Cam: pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    table = {"fancy": "fake_backend_mod:Cam"}
    with pytest.raises(BackendUnavailableError) as e:
        registry.load_backend("camera", "fancy", table)
    assert "placecell_missing_dependency_xyz" in str(e.value)
    assert "pip install" in str(e.value)
    assert "unknown" not in str(e.value)


def test_backends_are_imported_only_when_chosen() -> None:
    for module in ("hal.camera.v4l2", "hal.camera.libcamera", "hal.base.xr4000_can"):
        sys.modules.pop(module, None)
    registry.load_backend("camera", "sim")
    assert "hal.camera.v4l2" not in sys.modules
    assert "hal.base.xr4000_can" not in sys.modules


def test_every_registered_backend_resolves_or_says_what_is_missing() -> None:
    for kind, table in (("camera", registry.CAMERA_BACKENDS), ("base", registry.BASE_BACKENDS)):
        for name in table:
            try:
                cls = registry.load_backend(kind, name)
            except BackendUnavailableError as e:
                assert "pip install" in str(e)
            else:
                assert isinstance(cls, type)


def test_shared_context_builds_once() -> None:
    ctx = registry.HalContext(config=None)
    made = []
    a = ctx.shared("x", lambda: made.append(1) or object())
    b = ctx.shared("x", lambda: made.append(1) or object())
    assert a is b and made == [1]
