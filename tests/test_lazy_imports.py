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
    code = ("from vesselid.cli.app import main\n"
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


def test_static_names_equal_the_registries() -> None:
    """The CLI's static ``--method``/``--cov`` names (no kernels loaded) are the registries'."""
    from vesselid.core import names as _names
    from vesselid.identify import covariance_api
    from vesselid.identify.registry import DEFAULT_METHOD, ESTIMATORS
    from vesselid.identify.streaming import DEFAULT_STREAM_METHOD, STREAM_METHODS

    assert _names.METHODS == tuple(ESTIMATORS)
    assert _names.DEFAULT_METHOD == DEFAULT_METHOD
    assert _names.STREAM_METHODS == tuple(STREAM_METHODS)
    assert _names.DEFAULT_STREAM_METHOD == DEFAULT_STREAM_METHOD
    assert _names.COV_TYPES == tuple(covariance_api.available())
    assert _names.DEFAULT_COV_TYPE == covariance_api.default_cov_type()


def test_identify_does_not_import_scipy_stats() -> None:
    """``scipy.stats`` alone costs ~1 s of process start; the estimators use scipy.special."""
    code = ("import sys, vesselid.identify, vesselid.identify.registry\n"
            "print('STATS', 'scipy.stats' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert "STATS False" in out
