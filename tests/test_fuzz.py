"""Fuzz the command line with malformed logs, specs, sidecars and option values.

Property: every run ends with exit 2 and a one-line reason, or exit 0 with a
valid result (strict JSON) — never a traceback (an exception escaping
``vesselid.cli.app.main``), never ``NaN``/``Infinity`` in JSON. The CLI runs in-process on a
small log; examples are bounded so the whole module takes a few seconds.
"""

from __future__ import annotations

import contextlib
import io
import json
import string
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vesselid.cli import main

FUZZ = settings(max_examples=25, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow,
                                       HealthCheck.function_scoped_fixture])


def run(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def _no_constant(name: str) -> float:
    raise ValueError(f"invalid JSON constant {name}")


def assert_clean(code: int, out: str, err: str, *, json_out: bool = False) -> None:
    """Exit 2 with a one-line reason, or exit 0 (with strict JSON when asked for)."""
    assert code in (0, 2), (code, err)
    assert "Traceback" not in err
    if code == 2:
        lines = [ln for ln in err.strip().splitlines() if ln.strip()]
        assert len(lines) == 1 and "error:" in lines[0], err  # usage errors included
    elif json_out:
        payload = json.loads(out, parse_constant=_no_constant)
        assert isinstance(payload, dict) and "params" in payload


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("fuzz")
    code, _, err = run(["simulate", "--samples", "120", "--experiments", "2", "--seed", "3",
                        "--out", d / "t.csv"])
    assert code == 0, err
    return d


# ------------------------------------------------------------------------- logs (CSV)
cell = st.one_of(
    st.sampled_from(["", "nan", "NaN", "inf", "-inf", "1e309", "-1e308", "abc", "0x10",
                     "1,5", '"1"', "1e-320", "  ", "True", "None", "1e150", "9" * 400]),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.text(alphabet=string.printable, max_size=8),
)


@st.composite
def csv_mutation(draw, lines: list[str]):
    lines = list(lines)
    header = lines[0].split(",")
    kind = draw(st.sampled_from(["cell", "header-dup", "header-drop", "truncate", "swap",
                                 "ragged", "bytes", "empty-rows"]))
    if kind == "cell":
        for _ in range(draw(st.integers(1, 3))):
            i = draw(st.integers(1, len(lines) - 1))
            j = draw(st.integers(0, len(header) - 1))
            row = lines[i].split(",")
            row[j] = draw(cell)
            lines[i] = ",".join(row)
    elif kind == "header-dup":
        j = draw(st.integers(0, len(header) - 1))
        k = draw(st.integers(0, len(header) - 1))
        header[k] = header[j]
        lines[0] = ",".join(header)
    elif kind == "header-drop":
        j = draw(st.integers(0, len(header) - 1))
        lines = [",".join(x for n, x in enumerate(ln.split(",")) if n != j) for ln in lines]
    elif kind == "truncate":
        text = "\n".join(lines)
        return text[: draw(st.integers(0, len(text)))]
    elif kind == "swap":
        i = draw(st.integers(1, len(lines) - 2))
        lines[i], lines[i + 1] = lines[i + 1], lines[i]
    elif kind == "ragged":
        i = draw(st.integers(1, len(lines) - 1))
        lines[i] = lines[i] + "," + draw(cell)
    elif kind == "bytes":
        i = draw(st.integers(0, len(lines) - 1))
        lines[i] = draw(st.text(max_size=30))
    else:
        i = draw(st.integers(1, len(lines) - 1))
        lines.insert(i, "," * draw(st.integers(0, len(header))))
    return "\n".join(lines) + "\n"


@FUZZ
@given(data=st.data(), sidecar=st.booleans())
def test_malformed_csv_logs(base, tmp_path, data, sidecar):
    lines = (base / "t.csv").read_text().splitlines()
    text = data.draw(csv_mutation(lines))
    d = tmp_path / f"c{abs(hash(text)) % 10**9}"
    d.mkdir(exist_ok=True)
    (d / "t.csv").write_text(text, encoding="utf-8", errors="surrogateescape")
    if sidecar:
        (d / "t.json").write_text((base / "t.json").read_text())
    assert_clean(*run(["identify", d / "t.csv", "--model", base / "t.toml", "--json", "-"]),
                 json_out=True)


# ----------------------------------------------------------------------------- sidecars
json_value = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-10**20, 10**20),
              st.floats(allow_nan=False, allow_infinity=False), st.text(max_size=10)),
    lambda inner: st.one_of(st.lists(inner, max_size=3),
                            st.dictionaries(st.text(max_size=5), inner, max_size=3)),
    max_leaves=6,
)


@FUZZ
@given(data=st.data())
def test_malformed_sidecars(base, tmp_path, data):
    envelope = json.loads((base / "t.json").read_text())
    target = data.draw(st.sampled_from(["top", "metadata", "spec", "dtypes", "raw"]))
    if target == "raw":
        text = data.draw(st.text(max_size=60))
    else:
        table = {"top": envelope, "metadata": envelope["metadata"],
                 "spec": envelope["metadata"]["spec"], "dtypes": envelope["dtypes"]}[target]
        key = data.draw(st.sampled_from([*sorted(table), "extra"]))
        table[key] = data.draw(json_value)
        text = json.dumps(envelope)
    d = tmp_path / f"s{abs(hash(text)) % 10**9}"
    d.mkdir(exist_ok=True)
    (d / "t.csv").write_text((base / "t.csv").read_text())
    (d / "t.json").write_text(text)
    assert_clean(*run(["identify", d / "t.csv", "--json", "-"]), json_out=True)


# -------------------------------------------------------------------------------- specs
toml_scalar = st.one_of(st.booleans(), st.integers(-10**6, 10**6),
                        st.floats(allow_nan=True, allow_infinity=True),
                        st.text(alphabet=string.ascii_letters + "*|_ -+", max_size=8))
toml_value = st.recursive(
    toml_scalar,
    lambda inner: st.one_of(st.lists(inner, max_size=3),
                            st.dictionaries(st.sampled_from(["w", "tau", "a", "x"]), inner,
                                            max_size=2)),
    max_leaves=5,
)
GOOD = {"name": "heave", "states": ["w"], "inputs": ["tau"],
        "equations": {"w": ["w", "w*|w|", "tau"]}, "theta0": {"w": [0.99, -0.1, 1.0]},
        "dt": 1.0}


@FUZZ
@given(key=st.sampled_from([*GOOD, "aggregate", "colour"]), value=toml_value,
       nested=st.booleans())
def test_malformed_specs(base, tmp_path, key, value, nested):
    import tomli_w

    spec = json.loads(json.dumps(GOOD))
    if nested and isinstance(spec.get(key), dict):
        spec[key]["w"] = value
    else:
        spec[key] = value
    try:
        text = tomli_w.dumps(spec)
    except (TypeError, ValueError):
        return  # not representable in TOML
    path = tmp_path / f"s{abs(hash(text)) % 10**9}.toml"
    path.write_text(text)
    assert_clean(*run(["identify", base / "t.csv", "--model", path, "--json", "-"]),
                 json_out=True)


@FUZZ
@given(raw=st.binary(max_size=200))
def test_binary_specs(base, tmp_path, raw):
    path = tmp_path / "b.toml"
    path.write_bytes(raw)
    assert_clean(*run(["identify", base / "t.csv", "--model", path]))


# ------------------------------------------------------------------------------ options
count_text = st.one_of(
    st.integers(-5, 1).map(str),
    st.integers(10**12, 10**20).map(str),  # absurd sizes: refused by the size guard
    st.sampled_from(["abc", "1e3", "", "2.5", "nan", "0x10", "-0"]),
)


@FUZZ
@given(option=st.sampled_from(["--samples", "--experiments", "--seed"]), value=count_text)
def test_simulate_option_values(tmp_path, option, value):
    code, out, err = run(["simulate", "--samples", "50", option, value, "--out",
                          tmp_path / "x.csv"])
    assert_clean(code, out, err)
    if value.lstrip("-").isdigit() and (int(value) < 0 or (int(value) >= 10**12
                                                           and option != "--seed")):
        assert code == 2  # absurd or negative: refused


@FUZZ
@given(option=st.sampled_from(["--max-iter", "--method", "--combine"]),
       value=st.one_of(count_text, st.text(max_size=6)))
def test_identify_option_values(base, option, value):
    assert_clean(*run(["identify", base / "t.csv", option, value, "--json", "-"]),
                 json_out=True)


bad_count = st.one_of(st.integers(-10**6, -1).map(str),
                      st.sampled_from(["abc", "1e3", "", "2.5", "nan", "0x10", "--"]))


@FUZZ
@given(option=st.sampled_from(["--runs", "--samples", "--batch-size", "--seed"]),
       value=st.one_of(bad_count, st.integers(10**12, 10**20).map(str)))
def test_reproduce_option_values(option, value):
    """Invalid or absurd values only: a valid one would run a Monte Carlo study."""
    if option in ("--batch-size", "--seed") and value.isdigit():
        value = "-" + value
    code, out, err = run(["reproduce", "--runs", "2", "--samples", "10", option, value])
    assert_clean(code, out, err)
    assert code == 2


def test_fuzzed_json_never_holds_nan(base, tmp_path):
    """A log whose input is constant makes some statistics non-finite: JSON says null."""
    lines = (base / "t.csv").read_text().splitlines()
    j = lines[0].split(",").index("tau")
    rows = [ln.split(",") for ln in lines[1:]]
    for r in rows:
        r[j] = "0.2"
    (tmp_path / "t.csv").write_text("\n".join([lines[0], *(",".join(r) for r in rows)]) + "\n")
    code, out, err = run(["identify", tmp_path / "t.csv", "--model", base / "t.toml",
                          "--json", "-"])
    assert_clean(code, out, err, json_out=True)
    assert np.isfinite(code)


# ------------------------------------------------------- estimator and covariance options
@FUZZ
@given(method=st.one_of(st.sampled_from(["ls", "iv", "iv-zero-mean", "lagged-2sls", "sriv",
                                         "gmm", "auto"]), st.text(max_size=6)),
       combine=st.sampled_from(["pooled", "stacked", "", "Pooled"]),
       cov=st.one_of(st.sampled_from(["unadjusted", "hac", "cluster"]), st.text(max_size=5)),
       target=st.sampled_from(["measured", "aggregated", "x"]))
def test_identify_method_cov_combinations(base, method, combine, cov, target):
    """Every --method × --combine × --cov × --target: a valid fit or a one-line refusal
    (e.g. ``gmm`` with ``stacked``, ``cluster`` with two experiments, ``aggregated``
    without a current sensor)."""
    assert_clean(*run(["identify", base / "t.csv", "--method", method, "--combine", combine,
                       "--cov", cov, "--target", target, "--json", "-"]), json_out=True)


# ------------------------------------------------------------------ raw sensor streams
@pytest.fixture(scope="module")
def raw(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("raw")
    code, _, err = run(["simulate", "--system", "cybership2", "--samples", "700", "--seed", "2",
                        "--out", d / "cs.csv", "--raw", d / "raw"])
    assert code == 0, err
    return d / "raw"


real_text = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["abc", "", "1e309", "-0", "0", "1e-300", "95,0", "nan,nan", "1,2,3,4"]),
    st.text(alphabet=string.digits + ".,-e", max_size=8),
)


@FUZZ
@given(option=st.sampled_from(["--dt", "--origin", "--max-gap", "--min-duration"]),
       value=real_text)
def test_ingest_option_values(raw, tmp_path, option, value):
    argv = ["ingest", raw, "--out", tmp_path / "x.csv"]
    argv += [option, value] if option == "--dt" else ["--dt", "0.1", option, value]
    code, out, err = run(argv)
    assert_clean(code, out, err)
    if code == 0:  # a log was written: readable and finite
        from vesselid.data.logs import TrialLog

        data = TrialLog.load(tmp_path / "x.csv").data
        assert np.all(np.isfinite(data.select_dtypes("number").to_numpy()))


@FUZZ
@given(data=st.data())
def test_malformed_nmea_and_actuator_files(raw, tmp_path, data):
    """Corrupted sentences, checksums, clocks and CSV cells in the raw files: ingest
    writes a finite log (bad sentences counted in the quality report) or refuses."""
    import shutil
    import tempfile

    d = Path(tempfile.mkdtemp(dir=tmp_path)) / "raw"
    shutil.copytree(raw, d)
    name = data.draw(st.sampled_from(["nav.nmea", "actuators.csv", "ingest.toml"]))
    lines = (d / name).read_text().splitlines()
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(lines) - 1))
        kind = data.draw(st.sampled_from(["field", "drop", "dup", "garbage", "cut"]))
        parts = lines[i].split(",")
        if kind == "field" and len(parts) > 1:
            parts[data.draw(st.integers(0, len(parts) - 1))] = data.draw(cell)
            lines[i] = ",".join(parts)
        elif kind == "drop":
            del lines[i]
        elif kind == "dup":
            lines.insert(i, lines[i])
        elif kind == "garbage":
            lines[i] = data.draw(st.text(max_size=40))
        else:
            lines[i] = lines[i][: data.draw(st.integers(0, len(lines[i])))]
        if not lines:
            break
    (d / name).write_text("\n".join(lines) + "\n", encoding="utf-8", errors="surrogateescape")
    code, out, err = run(["ingest", d, "--dt", "0.1", "--out", d.parent / "x.csv"])
    assert_clean(code, out, err)


@FUZZ
@given(option=st.sampled_from(["--samples", "--experiments", "--wind-speed", "--vessel"]),
       value=st.one_of(bad_count, st.integers(10**11, 10**20).map(str),
                       st.sampled_from(["inf", "-inf", "nan", "1e400", "-3"])))
def test_plan_trial_option_values(option, value):
    """Invalid or absurd values only (a valid one would plan a trial: seconds); an absurd
    --wind-speed (10^11 m/s) simulates and is refused (no finite standard errors)."""
    if option == "--wind-speed" and value.isdigit():
        return  # tested once in test_plan_trial_absurd_wind (it simulates, ~1 s)
    code, out, err = run(["plan-trial", option, value])
    assert_clean(code, out, err)
    assert code == 2


def test_plan_trial_absurd_wind():
    """A finite but absurd wind (10^11 m/s) passes the option checks, simulates, and is
    refused with the reason (the disturbed simulation diverges), not a traceback."""
    code, out, err = run(["plan-trial", "--wind-speed", str(10**11)])
    assert_clean(code, out, err)
    assert code == 2 and err.strip()


def test_sea_trial_absurd_current_refused_without_warnings(tmp_path):
    """An absurd current (10^12 m/s) passes the option checks; the planner's prediction of
    the diverging design must not leak a RuntimeWarning (a second stderr line for a user),
    and the simulation is refused with its one-line reason. Whether the predicted variance
    rounds negative depends on the BLAS kernels: with ``OPENBLAS_CORETYPE=SkylakeX`` (this
    machine's own) the unguarded square root warned and this test failed; with the suite's
    pinned Haswell kernels it stays positive."""
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code, out, err = run(["sea-trial", "--experiments", "2", "--samples", "2000",
                              "--current-speed", "1e12", "--out", tmp_path / "st"])
    assert_clean(code, out, err)
    assert code == 2 and "diverged" in err
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)], \
        [str(w.message) for w in caught]
