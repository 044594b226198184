"""Import hygiene: a command loads only what it uses.

Each check runs a fresh interpreter and lists which heavy modules it left in
``sys.modules``; no timing is asserted here (timings live in ``scripts/bench.py``).
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

HEAVY = ("numba", "scipy", "matplotlib", "pandas", "gymnasium", "dask", "pyarrow")


def loaded_after(code: str) -> set[str]:
    probe = (code + "\nimport sys, json\n"
             f"print(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          check=True)
    return set(json.loads(proc.stdout.strip().splitlines()[-1]))


def test_import_vesselid_is_light() -> None:
    assert loaded_after("import vesselid") == set()


@pytest.mark.parametrize("argv", [
    ["--help"], ["--version"], [],
    ["identify", "--method", "nonsense", "x.csv"],
    ["identify", "--cov", "nonsense", "x.csv"],
    ["identify", "--stream", "--method", "gmm", "logs"],
])
def test_help_and_argument_errors_load_no_kernels(argv: list[str]) -> None:
    code = ("from vesselid.cli import main\n"
            "try:\n"
            f"    main({argv!r})\n"
            "except SystemExit:\n"
            "    pass\n")
    loaded = loaded_after(code)
    assert "numba" not in loaded and "matplotlib" not in loaded
    if argv in (["--help"], ["--version"], []):
        assert loaded == set()


def test_environments_registered_when_gymnasium_is_imported_later() -> None:
    code = ("import vesselid, sys\n"
            "assert 'gymnasium' not in sys.modules\n"
            "import gymnasium\n"
            "print('REG', 'vesselid/Heave-v0' in gymnasium.registry)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert "REG True" in out
    code = "import gymnasium, vesselid\nprint('REG', 'vesselid/Heave-v0' in gymnasium.registry)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert "REG True" in out


def test_lazy_top_level_names() -> None:
    import vesselid

    assert vesselid.ModelSpec.__name__ == "ModelSpec" and vesselid.Term.__name__ == "Term"
    assert set(vesselid.__all__) <= set(dir(vesselid))
    with pytest.raises(AttributeError):
        vesselid.nonexistent  # noqa: B018


def test_registry_names_are_the_estimators_and_covariances() -> None:
    """The registry's names, flags and defaults match the estimators they build."""
    from vesselid.identify import covariance_api, registry

    for e in registry.entries():
        est = registry.get_estimator(e.name)
        assert est.name == e.name
        assert e.closed_loop == (not getattr(est, "open_loop", True))
        assert e.multi_state == (e.name not in ("pem", "pem-switching"))
    assert registry.DEFAULT_METHOD in registry.names()
    assert set(registry.STREAM_METHODS) == {"ls", "iv", "iv-zero-mean"}
    assert registry.DEFAULT_STREAM_METHOD in registry.STREAM_METHODS
    assert registry.COV_TYPES == tuple(covariance_api.available())
    assert registry.DEFAULT_COV_TYPE == covariance_api.default_cov_type()


def test_registry_loads_no_estimator() -> None:
    """The command line checks ``--method`` against the registry without numba."""
    code = ("import sys, vesselid.identify.registry as r\n"
            "assert 'auto' in r.names() and 'pem' in r.ESTIMATORS\n"
            "print('NUMBA', 'numba' in sys.modules, 'PANDAS', 'pandas' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert "NUMBA False PANDAS False" in out, out


def test_identify_does_not_import_scipy_stats() -> None:
    """``scipy.stats`` alone costs ~1 s of process start; the estimators use scipy.special."""
    code = ("import sys, vesselid.identify, vesselid.identify.registry\n"
            "print('STATS', 'scipy.stats' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert "STATS False" in out
