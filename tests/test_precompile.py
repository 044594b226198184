"""The first-run helper process (vesselid.studies.precompile): what it compiles is what the
warm-up calls, and it starts only with cold caches."""

from __future__ import annotations

import pytest

pytest.importorskip("numba")

from numba.core.sigutils import normalize_signature

from vesselid.studies import precompile as _precompile
from vesselid.studies.reproduce import warm_up


@pytest.fixture(scope="module")
def warmed() -> None:
    warm_up()


def test_signatures_are_those_the_warm_up_compiles(warmed: None) -> None:
    # a drifted signature would make the helper compile a variant nobody calls
    for module, name, sig in _precompile.KERNELS:
        disp = _precompile._dispatcher(module, name)
        assert tuple(normalize_signature(sig)[0]) in [tuple(s) for s in disp.signatures], name


def test_no_helper_with_warm_caches(warmed: None, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("VESSELID_PRECOMPILE", "1")
    assert _precompile._cached(_precompile._dispatcher(*_precompile.KERNELS[0][:2]))
    assert _precompile.start() is None  # cached: nothing to compile


def test_disabled_and_busy(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(_precompile, "_cached", lambda disp: False)
    monkeypatch.setenv("VESSELID_PRECOMPILE", "0")
    assert _precompile.start() is None
    monkeypatch.delenv("VESSELID_PRECOMPILE")
    monkeypatch.setattr(_precompile, "_cores_idle", lambda: 1.0)  # one core busy
    assert _precompile.start() is None


def test_stop_none() -> None:
    _precompile.stop(None)
