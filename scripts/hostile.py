"""Hostile input, end to end: every bad-input case through the real CLI and the envs.

Each case runs ``python -m vesselid ...`` in a subprocess (or a short Python snippet for
the environments) in a scratch directory and is scored:

* ``traceback``: a Python traceback on stderr, or an exit code other than 0/2;
* ``silent``: a silent wrong answer — bad input accepted with exit 0, invalid JSON,
  leftover/partial files, or results that change when every signal is rescaled;
* ``slow refusal``: an absurd size not refused within 10 s;
* ``ok``: everything else (exit 2 with a one-line reason, or a valid result).

Run: ``python scripts/hostile.py`` (about 240 cases, 10-25 minutes on 2 busy cores;
``-k WORD`` runs the cases whose name contains WORD; ``--list`` lists them). Prints one
line per case and the counts; exits 1 if any case failed.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

TRACEBACK = "Traceback (most recent call last)"
REFUSE_SECONDS = 10.0


@dataclass
class Case:
    name: str
    argv: list[str] | None = None  # vesselid arguments
    expect: str = "refuse"  # refuse | ok | fast-refuse
    setup: Callable[[Path], None] | None = None
    check: Callable[[Path, subprocess.CompletedProcess], str | None] | None = None
    python: str | None = None  # a snippet instead of the CLI: exit 0 = correct behaviour
    env: dict[str, str] = field(default_factory=dict)
    timeout: float = 300.0


@dataclass
class Outcome:
    case: Case
    verdict: str  # ok | traceback | silent | slow
    detail: str
    seconds: float


# ------------------------------------------------------------------------------ fixtures
def run_cli(args: list[str], cwd: Path, env: dict[str, str] | None = None,
            timeout: float = 300.0) -> subprocess.CompletedProcess:
    full_env = {**os.environ, "MPLBACKEND": "Agg", **(env or {})}
    return subprocess.run([sys.executable, "-m", "vesselid", *args], cwd=cwd, env=full_env,
                          capture_output=True, text=True, timeout=timeout)


def make_log(d: Path, name: str = "t.csv", samples: int = 600, *extra: str) -> None:
    r = run_cli(["simulate", "--samples", str(samples), "--seed", "1", "--out", name, *extra], d)
    assert r.returncode == 0, r.stderr


def base_log(d: Path) -> None:
    make_log(d)


def edit_csv(fn: Callable[[list[str]], list[str]], sidecar: bool = True):
    def setup(d: Path) -> None:
        make_log(d)
        lines = (d / "t.csv").read_text().splitlines()
        (d / "t.csv").write_text("\n".join(fn(lines)) + "\n")
        if not sidecar:
            (d / "t.json").unlink()
    return setup


def set_cell(row: int, column: str, value: str) -> Callable[[list[str]], list[str]]:
    def edit(lines: list[str]) -> list[str]:
        j = lines[0].split(",").index(column)
        parts = lines[row].split(",")
        parts[j] = value
        return [*lines[:row], ",".join(parts), *lines[row + 1:]]
    return edit


def edit_sidecar(fn: Callable[[dict], object], raw: bytes | None = None):
    def setup(d: Path) -> None:
        make_log(d)
        side = d / "t.json"
        if raw is not None:
            side.write_bytes(raw)
            return
        env = json.loads(side.read_text())
        out = fn(env)
        side.write_text(out if isinstance(out, str) else json.dumps(env))
    return setup


def spec_file(text: str | bytes):
    def setup(d: Path) -> None:
        make_log(d)
        p = d / "s.toml"
        if isinstance(text, bytes):
            p.write_bytes(text)
        else:
            p.write_text(textwrap.dedent(text))
    return setup


GOOD_SPEC = """\
states = ["w"]
inputs = ["tau"]
[equations]
w = ["w", "w*|w|", "tau"]
"""


def spec_case(name: str, text: str | bytes) -> Case:
    return Case(f"spec: {name}", ["identify", "t.csv", "--model", "s.toml"],
                setup=spec_file(text))


def parquet_setup(kind: str):
    def setup(d: Path) -> None:
        import numpy as np
        import pandas as pd
        import pyarrow as pa
        import pyarrow.parquet as pq

        make_log(d, "t.parquet", 2000)
        p = d / "t.parquet"
        if kind == "corrupt-checksummed":
            raw = bytearray(p.read_bytes())
            for k in range(200, 1200, 97):
                raw[k] ^= 0x5A
            p.write_bytes(bytes(raw))
        elif kind == "corrupt-plain":  # garbage that decodes to huge finite values, as in
            # a file without page checksums (the issue saw values up to 3.7e306)
            df = pd.read_parquet(p)
            rows = np.random.default_rng(0).choice(len(df), 40, replace=False)
            df.loc[rows, "w"] = 3.7e306 * np.random.default_rng(1).uniform(-1, 1, 40)
            table = pa.Table.from_pandas(df, preserve_index=False)
            meta = dict(table.schema.metadata)
            meta[b"vesselid"] = pq.read_schema(p).metadata[b"vesselid"]
            pq.write_table(table.replace_schema_metadata(meta), p)
        elif kind == "truncated":
            p.write_bytes(p.read_bytes()[:-100])
        elif kind == "not-parquet":
            p.write_bytes(b"this is not parquet at all\n" * 10)
        elif kind == "duplicate-columns":
            table = pq.read_table(p)
            arrays = [table.column("experiment"), table.column("time"), table.column("w"),
                      table.column("tau"), table.column("w")]
            t2 = pa.Table.from_arrays(arrays, names=["experiment", "time", "w", "tau", "w"])
            t2 = t2.replace_schema_metadata(table.schema.metadata)
            pq.write_table(t2, p)
        elif kind == "metadata-not-json":
            table = pq.read_table(p)
            meta = dict(table.schema.metadata)
            meta[b"vesselid"] = b"\xff{not json"
            pq.write_table(table.replace_schema_metadata(meta), p)
        elif kind == "inf-value":
            df = pd.read_parquet(p)
            df.loc[5, "w"] = np.inf
            table = pa.Table.from_pandas(df, preserve_index=False)
            meta = dict(table.schema.metadata)
            meta[b"vesselid"] = pq.read_schema(p).metadata[b"vesselid"]
            pq.write_table(table.replace_schema_metadata(meta), p)
    return setup


def strict_json_check(d: Path, r: subprocess.CompletedProcess) -> str | None:
    if r.returncode != 0:
        return None
    try:
        json.loads(r.stdout, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
    except ValueError as exc:
        return f"invalid JSON on stdout: {exc}"
    return None


def constant_input(d: Path) -> None:
    make_log(d, "t.csv", 600, "--experiments", "2")
    lines = (d / "t.csv").read_text().splitlines()
    head = lines[0].split(",")
    j = head.index("tau")
    out = [lines[0]]
    for line in lines[1:]:
        parts = line.split(",")
        parts[j] = "0.2"
        out.append(",".join(parts))
    (d / "t.csv").write_text("\n".join(out) + "\n")


def constant_everything(d: Path) -> None:
    make_log(d, "t.csv", 600, "--experiments", "2")
    lines = (d / "t.csv").read_text().splitlines()
    head = lines[0].split(",")
    out = [lines[0]]
    for line in lines[1:]:
        parts = line.split(",")
        for name in ("w", "tau", "w_c"):
            if name in head:
                parts[head.index(name)] = "0.5"
        out.append(",".join(parts))
    (d / "t.csv").write_text("\n".join(out) + "\n")


#: The estimators of one state equation without a disturbance sensor (the scale cases
#: give them the spec without the current meter).
LIKELIHOOD_METHODS = ("pem", "pem-switching")


def scaled(factor: float):
    def setup(d: Path) -> None:
        import pandas as pd

        make_log(d, "t.csv", 4000, "--experiments", "2", "--current-mean", "0.1")
        # the spec without the current meter's [aggregate] relation (for the likelihood
        # estimators, which do not model a disturbance sensor)
        (d / "p.toml").write_text(GOOD_SPEC)
        df = pd.read_csv(d / "t.csv")
        for c in df.columns:
            if c not in ("experiment", "time"):
                df[c] = df[c] * factor
        df.to_csv(d / "s.csv", index=False, float_format="%.17g")
    return setup


def scale_check(factor: float, method: str, combine: str = "pooled", model: str = "t.toml"):
    def check(d: Path, r: subprocess.CompletedProcess) -> str | None:
        if r.returncode != 0:
            return None if factor > 1e100 else f"scaled log refused: {r.stderr.strip()[-200:]}"
        ref = run_cli(["identify", "t.csv", "--model", model, "--method", method,
                       "--combine", combine, "--json", "-"], d)
        a = json.loads(ref.stdout)["params"]["w"]
        b = json.loads(r.stdout)["params"]["w"]
        # x -> s x: a and f unchanged, the modulus coefficient scales by 1/s
        pairs = [(a["w"], b["w"]), (a["w*|w_r|"] if "w*|w_r|" in a else a[list(a)[1]],
                                    b[list(b)[1]] * factor), (a["tau"], b["tau"])]
        # the likelihood estimators stop where the next step is below 0.01 standard
        # errors (pem.SCORING_TOL, switching.TOL): signals in other units take a path that
        # differs at rounding and may stop elsewhere within that; the closed forms and the
        # refined iterations agree to 1e-8
        se = json.loads(ref.stdout)["stderr"]["w"]
        for (x, y), key in zip(pairs, ("w", list(a)[1], "tau"), strict=True):
            tol = 0.01 * se[key] if method in LIKELIHOOD_METHODS else 0.0
            if not (math.isclose(x, y, rel_tol=1e-8, abs_tol=1e-12) or abs(x - y) <= tol):
                return f"results change with the units: {a} vs {b} (x{factor:g})"
        return None
    return check


def leftover_check(expect_files: set[str]):
    def check(d: Path, r: subprocess.CompletedProcess) -> str | None:
        names = {p.name for p in d.iterdir()}
        hidden = sorted(n for n in names if n.endswith(".tmp"))
        if hidden:
            return f"temporary files left behind: {hidden}"
        if not names <= expect_files | {"t.csv", "t.json", "t.toml", "ro", "file", "dir.csv"}:
            return f"unexpected files: {sorted(names - expect_files)}"
        return None
    return check


def partial_output_setup(d: Path) -> None:
    (d / "p.json").mkdir()  # the sidecar target is a directory: the write must fail


def partial_output_check(d: Path, r: subprocess.CompletedProcess) -> str | None:
    left = sorted(p.name for p in d.iterdir() if p.name != "p.json")
    return f"partial output left behind: {left}" if left else None


def killed_write(d: Path) -> str | None:
    """SIGKILL a long write, then write again: no hidden .tmp files may remain."""
    env = {**os.environ, "MPLBACKEND": "Agg"}
    proc = subprocess.Popen([sys.executable, "-m", "vesselid", "simulate", "--samples",
                             "2000000", "--out", "k.csv"], cwd=d, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while time.time() < deadline and not any(p.name.endswith(".tmp") for p in d.iterdir()):
        time.sleep(0.2)
    time.sleep(1.0)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    r = run_cli(["simulate", "--samples", "200", "--out", "k.csv"], d)
    if r.returncode != 0:
        return f"rewrite failed: {r.stderr.strip()}"
    left = sorted(p.name for p in d.iterdir() if p.name.endswith(".tmp"))
    return f"killed write left {left}" if left else None


def terminated_write(d: Path) -> str | None:
    """SIGTERM during a write removes the temporary files at once."""
    env = {**os.environ, "MPLBACKEND": "Agg"}
    proc = subprocess.Popen([sys.executable, "-m", "vesselid", "simulate", "--samples",
                             "2000000", "--out", "k.csv"], cwd=d, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while time.time() < deadline and not any(p.name.endswith(".tmp") for p in d.iterdir()):
        time.sleep(0.2)
    time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate()
    left = sorted(p.name for p in d.iterdir())
    if TRACEBACK in err:
        return "traceback:" + err.strip().splitlines()[-1]
    return f"terminated write left {left}" if left else None


def streamed_write(d: Path) -> str | None:
    """A 10^7-sample log (3 time chunks) written with bounded memory (``--long`` only)."""
    import resource

    import pyarrow.parquet as pq

    r = run_cli(["simulate", "--samples", "10000000", "--out", "big.parquet"], d, timeout=3600)
    if r.returncode != 0:
        return f"failed: {r.stderr.strip()[-200:]}"
    rows = pq.read_metadata(d / "big.parquet").num_rows
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024
    if rows != 10_000_000:
        return f"wrote {rows} rows"
    # the whole log in memory would be 10^7 x 7 x 8 B = 560 MB of data (~2 GB peak before)
    return None if peak < 1.5e9 else f"peak memory {peak / 1e9:.2f} GB"


_RAW_CACHE: list[Path] = []


def raw_dir(mutate: Callable[[Path], None] | None = None):
    """A copy of ``simulate --system cybership2 --raw`` output in ``d/raw`` (made once per
    run), optionally mutated."""
    def setup(d: Path) -> None:
        if not _RAW_CACHE:
            cache = Path(tempfile.mkdtemp(prefix="vesselid-hostile-raw-"))
            r = run_cli(["simulate", "--system", "cybership2", "--samples", "700", "--seed",
                         "2", "--out", "cs.csv", "--raw", "raw"], cache)
            assert r.returncode == 0, r.stderr
            _RAW_CACHE.append(cache)
        shutil.copytree(_RAW_CACHE[0] / "raw", d / "raw")
        for name in ("cs.csv", "cs.json", "cs.toml"):
            shutil.copy(_RAW_CACHE[0] / name, d / name)
        if mutate is not None:
            mutate(d / "raw")
    return setup


def _edit_lines(name: str, fn: Callable[[list[str]], list[str]]):
    def mutate(raw: Path) -> None:
        p = raw / name
        p.write_text("\n".join(fn(p.read_text().splitlines())) + "\n")
    return mutate


def _bad_checksums(lines: list[str]) -> list[str]:
    return [ln[:-2] + ("00" if ln[-2:] != "00" else "11") if "*" in ln else ln for ln in lines]


def _sparse_nmea(raw: Path) -> None:
    with open(raw / "nav.nmea", "r+b") as fh:
        fh.truncate(200 * 10**9)


def ingested_log_check(d: Path, r: subprocess.CompletedProcess) -> str | None:
    """ingest exit 0: the log it wrote loads, holds only finite numbers and identifies."""
    if r.returncode != 0:
        return None
    import numpy as np
    import pandas as pd

    out = next((p for p in d.iterdir() if p.name.startswith("x.")
                and p.suffix in (".csv", ".parquet")), None)
    if out is None:
        return "exit 0 but no log written"
    data = pd.read_csv(out) if out.suffix == ".csv" else pd.read_parquet(out)
    if not np.all(np.isfinite(data.select_dtypes("number").to_numpy())):
        return "ingested log holds NaN/inf"
    return None


def no_files_check(*names: str):
    def check(d: Path, r: subprocess.CompletedProcess) -> str | None:
        left = sorted(n for n in names if (d / n).exists())
        return f"refused, but wrote {left}" if left else None
    return check


def sparse_csv(d: Path) -> None:
    """A 200 GB sparse CSV (no disk used) with a plausible header and first lines."""
    make_log(d)
    head = "".join((d / "t.csv").read_text().splitlines(keepends=True)[:50])
    p = d / "huge.csv"
    with open(p, "wb") as fh:
        fh.write(head.encode())
        fh.truncate(200 * 10**9)


# ------------------------------------------------------- real-vessel NMEA, tables, bags
#: the vessel of the synthetic real-format logs: 3 m/s on a true heading of 30 degrees
REAL_U, REAL_PSI_DEG = 3.0, 30.0


def real_nmea(*kinds: str, n: int = 120):
    """A 1 Hz NMEA log in the formats real vessels send (RMC, ZDA, VTG, HDT, HDG with or
    without variation, HDT with empty fields), one sentence of each kind per second."""
    def setup(d: Path) -> None:
        import numpy as np

        from vesselid.data.nmea0183 import KNOT, sentence_lines

        t = 1_780_308_000.0 + np.arange(n)
        hms = [time.strftime("%H%M%S", time.gmtime(x)) + ".00" for x in t]
        psi = math.radians(REAL_PSI_DEG)
        north, east = REAL_U * math.cos(psi) * (t - t[0]), REAL_U * math.sin(psi) * (t - t[0])
        lat = 63.43 + north / 111_320.0
        lon = 10.39 + east / (111_320.0 * math.cos(math.radians(63.43)))
        la = [f"{int(x):02d}{(x - int(x)) * 60:010.7f}" for x in lat]
        lo = [f"{int(x):03d}{(x - int(x)) * 60:010.7f}" for x in lon]
        kn = f"{REAL_U / KNOT:.4f}"
        c = [""] * n
        one = {
            "RMC": lambda: sentence_lines("GP", "RMC", [hms, ["A"] * n, la, ["N"] * n, lo,
                                                        ["E"] * n, [kn] * n, ["30.0"] * n,
                                                        ["010626"] * n, c, c, ["A"] * n]),
            "ZDA": lambda: sentence_lines("GP", "ZDA", [hms, ["01"] * n, ["06"] * n,
                                                        ["2026"] * n, ["00"] * n, ["00"] * n]),
            "VTG": lambda: sentence_lines("GP", "VTG", [["30.0"] * n, ["T"] * n, c, ["M"] * n,
                                                        [kn] * n, ["N"] * n, c, ["K"] * n,
                                                        ["A"] * n]),
            "HDT": lambda: sentence_lines("HE", "HDT", [["30.0"] * n, ["T"] * n]),
            "HDT-empty": lambda: sentence_lines("II", "HDT", [c, ["T"] * n]),
            "HDG": lambda: sentence_lines("HC", "HDG", [["33"] * n, c, c, ["3.0"] * n,
                                                        ["W"] * n]),
            "HDG-novar": lambda: sentence_lines("HC", "HDG", [["33"] * n]),
        }
        groups = [one[k]() for k in kinds]
        (d / "raw").mkdir()
        (d / "raw" / "nav.nmea").write_text(
            "\n".join(x for row in zip(*groups, strict=True) for x in row) + "\n")
    return setup


def real_log_check(d: Path, r: subprocess.CompletedProcess) -> str | None:
    """ingest exit 0 on a real-format log: u = 3 m/s and the true heading 30 degrees."""
    problem = ingested_log_check(d, r)
    if problem or r.returncode != 0:
        return problem
    import pandas as pd

    data = pd.read_csv(d / "x.csv")
    psi = float((data["psi"].median() + math.pi) % (2 * math.pi) - math.pi)
    if abs(psi - math.radians(REAL_PSI_DEG)) > 1e-3 or abs(data["u"].median() - REAL_U) > 1e-2:
        return f"wrong values: psi {math.degrees(psi):.3f} deg, u {data['u'].median():.4f} m/s"
    return None


def quantised_table(d: Path, rate: float = 7.39, n: int = 3000) -> None:
    """A table whose time column has 3 significant digits (each stamp repeated ~7 times)."""
    raw = d / "raw"
    raw.mkdir()
    rows = ["time,u,v,r,psi"]
    for k in range(n):
        rows.append(f"{float(f'{100.0 + k / rate:.3g}'):.6g},{1.0 + 0.001 * (k % 50):.6f},"
                    f"0.0,0.01,{0.01 * k / rate:.6f}")
    (raw / "tank.csv").write_text("\n".join(rows) + "\n")
    (raw / "ingest.toml").write_text('[[csv]]\nfile = "tank.csv"\n'
                                     'columns = { u = "u", v = "v", r = "r", psi = "psi" }\n')


def all_rows_check(span_s: float):
    def check(d: Path, r: subprocess.CompletedProcess) -> str | None:
        problem = ingested_log_check(d, r)
        if problem or r.returncode != 0:
            return problem
        import pandas as pd

        t = pd.read_csv(d / "x.csv")["time"]
        if abs(float(t.iloc[-1]) - span_s) > 0.5:
            return f"rows dropped: the log spans {float(t.iloc[-1]):.1f} s of {span_s:.1f} s"
        return None
    return check


def retimed_log(fn_name: str):
    """t.csv (heave, spec dt = 1 s) with its time column rewritten."""
    def setup(d: Path) -> None:
        import numpy as np
        import pandas as pd

        make_log(d)
        df = pd.read_csv(d / "t.csv")
        if fn_name == "0.1 s":
            df["time"] = df["time"] * 0.1
        else:
            df["time"] = np.cumsum(np.random.default_rng(0).uniform(0.05, 3.0, len(df)))
        df.to_csv(d / "t.csv", index=False, float_format="%.17g")
    return setup


def ros1_bag(truncate: bool):
    def setup(d: Path) -> None:
        if not truncate:
            (d / "x.bag").write_bytes(b"#ROSBAG V2.0\n" + os.urandom(30000))
            return
        from rosbags.rosbag1 import Writer
        from rosbags.typesys import Stores, get_typestore

        ts = get_typestore(Stores.ROS1_NOETIC)
        T = ts.types
        with Writer(d / "x.bag") as w:
            c = w.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=ts)
            for i in range(2000):
                hdr = T["std_msgs/msg/Header"](seq=i, stamp=T["builtin_interfaces/msg/Time"](
                    sec=1_780_000_000 + i // 10, nanosec=(i % 10) * 100_000_000), frame_id="b")
                v = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.01)
                q = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
                import numpy as np

                m = T["sensor_msgs/msg/Imu"](header=hdr, orientation=q,
                                             orientation_covariance=np.zeros(9),
                                             angular_velocity=v,
                                             angular_velocity_covariance=np.zeros(9),
                                             linear_acceleration=v,
                                             linear_acceleration_covariance=np.zeros(9))
                w.write(c, (1_780_000_000 + i // 10) * 10**9 + (i % 10) * 10**8,
                        ts.serialize_ros1(m, "sensor_msgs/msg/Imu"))
        size = (d / "x.bag").stat().st_size
        with open(d / "x.bag", "r+b") as fh:
            fh.truncate(size // 2)
    return setup


MISSING_EXTRA = """
import sys
sys.modules["pynmea2"] = None  # as after a plain `pip install .`
import io, contextlib
from vesselid.cli import main
err = io.StringIO()
with contextlib.redirect_stderr(err):
    rc = main(["ingest", "raw", "--dt", "1", "--out", "x.csv"])
msg = err.getvalue().strip()
print(rc, msg)
sys.exit(0 if rc == 2 and len(msg.splitlines()) == 1 and "vesselid[raw]" in msg else 3)
"""


#: identify() from Python on a retimed t.csv (setup ``retimed_log``): refused with one line
#: naming ``ingest --dt`` (a SamplingError, a ValueError), never an estimate at the wrong dt.
API_SAMPLING = """
import sys
from vesselid.identify import identify
from vesselid.data.logs import TrialLog
from vesselid.model.spec import ModelSpec
log, spec = TrialLog.load("t.csv"), ModelSpec.load("t.toml")
try:
    res = identify(log, spec, {options})
except ValueError as exc:
    msg = str(exc)
    print(type(exc).__name__, msg)
    sys.exit(0 if len(msg.splitlines()) == 1 and {expect!r} in msg else 3)
print("accepted:", res.status)
sys.exit(3)
"""


def readonly_dir(d: Path) -> str:
    ro = d / "ro"
    ro.mkdir()
    os.chmod(ro, 0o555)
    if os.access(ro, os.W_OK):  # root ignores permissions: use a place nobody can write
        return "/proc/vesselid-hostile/x.csv"
    return "ro/x.csv"


# ----------------------------------------------------------------------- environments
ENV_SNIPPET = """
import sys, numpy as np, gymnasium as gym
import vesselid.envs  # noqa
from vesselid.envs import {cls}
kind = {kind!r}
vector = {vector!r}
if vector:
    env = {cls}(num_envs=3)
else:
    env = {cls}()
shape = env.action_space.shape
if kind != "before-reset":
    env.reset(seed=0)
if kind == "nan":
    a = np.full(shape, np.nan, dtype=np.float32)
elif kind == "inf":
    a = np.full(shape, np.inf, dtype=np.float32)
elif kind == "wrong-shape":
    a = np.zeros((shape[0] + 1,) + shape[1:], dtype=np.float32)
elif kind == "scalar":
    a = 0.1
elif kind == "before-reset":
    a = env.action_space.sample()
try:
    out = env.step(a)
except (ValueError, TypeError, gym.error.Error) as exc:
    msg = str(exc).strip()
    print("raised:", type(exc).__name__, msg)
    sys.exit(0 if msg else 3)
obs, rew = out[0], out[1]
print("accepted; finite obs:", bool(np.all(np.isfinite(obs))), "reward:", rew)
sys.exit(4)
"""


def env_case(cls: str, kind: str, vector: bool) -> Case:
    return Case(f"env: {cls} {kind}", python=ENV_SNIPPET.format(cls=cls, kind=kind,
                                                                vector=vector))


#: every registered estimator (``identify --method``; the static list the command line
#: checks, which tests/test_lazy_imports.py holds equal to the registry)
from vesselid.identify.registry import METHODS  # noqa: E402

#: the estimators that run on an open-loop log (``cl-iv`` needs a closed-loop one and
#: refuses these logs: its own case below)
OPEN_LOOP_METHODS = tuple(m for m in METHODS if m != "cl-iv")


# ----------------------------------------------------------------------------- cases
def cases(long: bool = False) -> list[Case]:
    ident = ["identify", "t.csv"]
    c: list[Case] = []
    if long:
        c.append(Case("size: simulate 1e7 samples streams to disk in chunks", python="STREAM"))
    # -- absurd sizes: refused before allocation, in < 10 s
    for name, argv in [
        ("simulate 1e11 experiments", ["simulate", "--samples", "100", "--experiments",
                                       "100000000000", "--out", "big.csv"]),
        ("simulate 1e12 samples", ["simulate", "--samples", "1000000000000", "--out", "b.csv"]),
        ("simulate 1e12 samples parquet", ["simulate", "--samples", "1000000000000", "--out",
                                           "b.parquet"]),
        ("simulate 1e9 x 1e4 cybership2", ["simulate", "--system", "cybership2", "--samples",
                                           "1000000000", "--experiments", "10000", "--out",
                                           "b.csv"]),
        ("reproduce 1e12 runs", ["reproduce", "--runs", "1000000000000"]),
        ("reproduce 1e12 samples", ["reproduce", "--runs", "2", "--samples", "1000000000000"]),
        ("reproduce 1e9 batch", ["reproduce", "--runs", "1000000000", "--batch-size",
                                 "1000000000"]),
        ("sea-trial 1e8 experiments", ["sea-trial", "--experiments", "100000000", "--samples",
                                       "100000", "--out", "st"]),
        ("sea-trial 1e12 samples", ["sea-trial", "--samples", "1000000000000", "--out", "st"]),
        ("plan-trial 1e11 samples", ["plan-trial", "--samples", "100000000000"]),
    ]:
        c.append(Case(f"size: {name}", argv, expect="fast-refuse"))
    c.append(Case("size: identify a 200 GB (sparse) CSV", ["identify", "huge.csv", "--model",
                                                          "t.toml"],
                  expect="fast-refuse", setup=sparse_csv))
    c.append(Case("size: ingest a 200 GB (sparse) NMEA file", ["ingest", "raw", "--dt", "0.1",
                                                             "--out", "x.csv"],
                  expect="fast-refuse", setup=raw_dir(_sparse_nmea)))
    c.append(Case("size: ingest --dt 1e-9 (a 10^12-point grid)", ["ingest", "raw", "--dt", "1e-9",
                                                                  "--out", "x.csv"],
                  expect="fast-refuse", setup=raw_dir()))
    c.append(Case("size: VESSELID_MAX_MEMORY=100M ingest", ["ingest", "raw", "--dt", "0.1",
                                                           "--out", "x.csv"],
                  expect="fast-refuse", setup=raw_dir(), env={"VESSELID_MAX_MEMORY": "100M"}))
    c.append(Case("size: VESSELID_MAX_MEMORY=10M simulate 1e6", ["simulate", "--samples",
                                                                 "1000000", "--out", "m.csv"],
                  expect="fast-refuse", env={"VESSELID_MAX_MEMORY": "10M"}))
    c.append(Case("size: VESSELID_MAX_SECONDS=1 reproduce", ["reproduce"],
                  expect="fast-refuse", env={"VESSELID_MAX_SECONDS": "1"}))
    # -- command-line options
    for name, argv in [
        ("--max-iter 0", [*ident, "--max-iter", "0"]),
        ("--max-iter -5", [*ident, "--max-iter", "-5"]),
        ("--seed -1 simulate", ["simulate", "--seed", "-1", "--out", "x.csv"]),
        ("--seed -1 reproduce", ["reproduce", "--seed", "-1", "--runs", "2"]),
        ("--seed -1 sea-trial", ["sea-trial", "--seed", "-1", "--out", "st"]),
        ("--seed abc", ["simulate", "--seed", "abc", "--out", "x.csv"]),
        ("--samples 0", ["simulate", "--samples", "0", "--out", "x.csv"]),
        ("--samples 1", ["simulate", "--samples", "1", "--out", "x.csv"]),
        ("--samples -7", ["simulate", "--samples", "-7", "--out", "x.csv"]),
        ("--samples 1e3", ["simulate", "--samples", "1e3", "--out", "x.csv"]),
        ("--experiments 0", ["simulate", "--experiments", "0", "--out", "x.csv"]),
        ("--current-mean nan", ["simulate", "--current-mean", "nan", "--out", "x.csv"]),
        ("--current-mean inf", ["simulate", "--current-mean", "inf", "--out", "x.csv"]),
        ("--system nope", ["simulate", "--system", "nope", "--out", "x.csv"]),
        ("cybership2 --current-mean", ["simulate", "--system", "cybership2", "--current-mean",
                                       "0.1", "--out", "x.csv"]),
        ("cybership2 --current-sensor", ["simulate", "--system", "cybership2",
                                         "--current-sensor", "--out", "x.csv"]),
        ("--out x.txt", ["simulate", "--out", "x.txt"]),
        ("--method bogus", [*ident, "--method", "bogus"]),
        ("reproduce --runs 1", ["reproduce", "--runs", "1"]),
        ("reproduce --batch-size 0", ["reproduce", "--runs", "2", "--batch-size", "0"]),
        ("reproduce --samples 5", ["reproduce", "--runs", "2", "--samples", "5"]),
        ("reproduce --xi-mean nan", ["reproduce", "--runs", "2", "--samples", "50",
                                     "--xi-mean", "abc"]),
        ("sea-trial --experiments 1", ["sea-trial", "--experiments", "1", "--out", "st"]),
        ("sea-trial --wind-speed nan", ["sea-trial", "--wind-speed", "nan", "--out", "st"]),
        ("sea-trial --wave-direction nan", ["sea-trial", "--wave-direction", "nan", "--out",
                                            "st"]),
        ("sea-trial --wave-height inf", ["sea-trial", "--wave-height", "inf", "--out", "st"]),
        ("sea-trial --wave-period 0", ["sea-trial", "--wave-period", "0", "--out", "st"]),
        ("sea-trial --current-speed 1e12 (diverges)", ["sea-trial", "--experiments", "2",
                                                       "--samples", "2000", "--current-speed",
                                                       "1e12", "--out", "st"]),
        ("plan-trial --experiments 0", ["plan-trial", "--experiments", "0"]),
        ("plan-trial --samples -1", ["plan-trial", "--samples", "-1"]),
        ("plan-trial --wind-speed inf", ["plan-trial", "--wind-speed", "inf"]),
        ("unknown command", ["frobnicate"]),
        ("identify --method gmm --combine stacked", [*ident, "--method", "gmm", "--combine",
                                                     "stacked"]),
        ("identify --cov bogus", [*ident, "--cov", "bogus"]),
        ("identify --combine bogus", [*ident, "--combine", "bogus"]),
        ("identify --target aggregated without a sensor", [*ident, "--target", "aggregated"]),
        ("plan-trial --vessel nope", ["plan-trial", "--vessel", "nope"]),
        ("plan-trial --samples abc", ["plan-trial", "--samples", "abc"]),
        ("plan-trial --wind-speed 1e11 (simulations diverge)",
         ["plan-trial", "--samples", "2000", "--experiments", "2", "--wind-speed", "1e11"]),
    ]:
        c.append(Case(f"option: {name}", argv, setup=base_log))
    ingest = ["ingest", "raw", "--out", "x.csv"]
    for name, argv in [
        ("--dt abc", [*ingest, "--dt", "abc"]),
        ("--dt 0", [*ingest, "--dt", "0"]),
        ("--dt nan", [*ingest, "--dt", "nan"]),
        ("--dt -1", [*ingest, "--dt", "-1"]),
        ("--dt 1e9", [*ingest, "--dt", "1e9"]),
        ("--origin nan,nan", [*ingest, "--dt", "0.1", "--origin", "nan,nan"]),
        ("--origin 95,0 (latitude out of range)", [*ingest, "--dt", "0.1", "--origin", "95,0"]),
        ("--origin abc", [*ingest, "--dt", "0.1", "--origin", "abc"]),
        ("--origin 1,2,3,4", [*ingest, "--dt", "0.1", "--origin", "1,2,3,4"]),
        ("--max-gap nan", [*ingest, "--dt", "0.1", "--max-gap", "nan"]),
        ("--max-gap -1", [*ingest, "--dt", "0.1", "--max-gap", "-1"]),
        ("--min-duration nan", [*ingest, "--dt", "0.1", "--min-duration", "nan"]),
        ("--min-duration -5", [*ingest, "--dt", "0.1", "--min-duration", "-5"]),
        ("--min-duration 1e12", [*ingest, "--dt", "0.1", "--min-duration", "1e12"]),
        ("--out x.txt", ["ingest", "raw", "--dt", "0.1", "--out", "x.txt"]),
        ("--config missing", [*ingest, "--dt", "0.1", "--config", "nope.toml"]),
        ("--config a directory", [*ingest, "--dt", "0.1", "--config", "raw"]),
        ("input missing", ["ingest", "nope", "--dt", "0.1", "--out", "x.csv"]),
    ]:
        c.append(Case(f"option: ingest {name}", argv, setup=raw_dir(),
                      check=ingested_log_check))
    # -- raw sensor files (ingest)
    c += [
        Case("raw: ingest the streams simulate --raw wrote", [*ingest, "--dt", "0.1"],
             expect="ok", setup=raw_dir(), check=ingested_log_check),
        Case("raw: ingest an empty directory", ["ingest", "e", "--dt", "0.1", "--out", "x.csv"],
             setup=lambda d: (d / "e").mkdir()),
        Case("raw: binary garbage .nmea", [*ingest, "--dt", "0.1"],
             setup=raw_dir(lambda r: (r / "nav.nmea").write_bytes(os.urandom(20000)))),
        Case("raw: every NMEA checksum wrong", [*ingest, "--dt", "0.1"],
             setup=raw_dir(_edit_lines("nav.nmea", _bad_checksums))),
        Case("raw: NMEA truncated mid-sentence", [*ingest, "--dt", "0.1"], expect="any",
             setup=raw_dir(_edit_lines("nav.nmea", lambda ls: [*ls[:-1], ls[-1][:9]])),
             check=ingested_log_check),
        Case("raw: NMEA clock jumps back an hour", [*ingest, "--dt", "0.1"], expect="any",
             setup=raw_dir(_edit_lines("nav.nmea", lambda ls: [
                 ln.replace(",12", ",11", 1) if k % 50 == 7 else ln for k, ln in enumerate(ls)])),
             check=ingested_log_check),
        Case("raw: ingest.toml invalid TOML", [*ingest, "--dt", "0.1"],
             setup=raw_dir(_edit_lines("ingest.toml", lambda ls: [*ls, "[[["]))),
        Case("raw: ingest.toml unknown key", [*ingest, "--dt", "0.1"],
             setup=raw_dir(_edit_lines("ingest.toml", lambda ls: ["colour = 1", *ls]))),
        Case("raw: ingest.toml origin out of range", [*ingest, "--dt", "0.1"],
             setup=raw_dir(_edit_lines("ingest.toml", lambda ls: [
                 "origin = [123.0, 10.0]",
                 *[x for x in ls if not x.startswith(("origin", " ", "]"))]]))),
        Case("raw: actuators.csv column renamed", [*ingest, "--dt", "0.1"],
             setup=raw_dir(_edit_lines("actuators.csv", lambda ls: [
                 ls[0].replace("X_cmd", "Q_cmd"), *ls[1:]]))),
        Case("raw: actuators.csv with NaN and text cells (skipped, counted)",
             [*ingest, "--dt", "0.1"], expect="any", check=ingested_log_check,
             setup=raw_dir(_edit_lines("actuators.csv", lambda ls: [
                 ls[0], *[ln if k % 9 else ln.split(",")[0] + ",abc,nan,1"
                          for k, ln in enumerate(ls[1:])]]))),
        Case("raw: actuators.csv duplicated column names", [*ingest, "--dt", "0.1"],
             setup=raw_dir(_edit_lines("actuators.csv", lambda ls: [
                 ls[0].replace("Y_cmd", "X_cmd"), *ls[1:]]))),
        Case("raw: actuators.csv an extra column repeating X_cmd", [*ingest, "--dt", "0.1"],
             setup=raw_dir(_edit_lines("actuators.csv", lambda ls: [
                 ls[0] + ",X_cmd", *[ln + ",0" for ln in ls[1:]]]))),
        # real-vessel formats: magnetic headings, ZDA time, quantised tables, dt, bags
        Case("nmea: HDG-only heading (magnetic, variation in the sentence)",
             [*ingest, "--dt", "1", "--min-duration", "10"], expect="ok",
             setup=real_nmea("RMC", "HDG"), check=real_log_check),
        Case("nmea: HDG without a variation anywhere", [*ingest, "--dt", "1"],
             setup=real_nmea("RMC", "HDG-novar")),
        Case("nmea: ZDA-only time (VTG + HDT, no RMC/GGA)",
             [*ingest, "--dt", "1", "--min-duration", "10"], expect="ok",
             setup=real_nmea("ZDA", "VTG", "HDT"), check=real_log_check),
        Case("nmea: no time source (VTG + HDT only)", [*ingest, "--dt", "1"],
             setup=real_nmea("VTG", "HDT")),
        Case("nmea: every heading field empty", [*ingest, "--dt", "1"],
             setup=real_nmea("ZDA", "VTG", "HDT-empty")),
        Case("table: quantised time column (3 significant digits)",
             [*ingest, "--dt", "0.1", "--min-duration", "5"], setup=quantised_table),
        Case("table: quantised time column, --sample-rate 7.39",
             [*ingest, "--dt", "0.1", "--min-duration", "5", "--sample-rate", "7.39"],
             expect="ok", setup=quantised_table, check=all_rows_check(2999 / 7.39)),
        Case("table: quantised time column, a wrong --sample-rate 7.2",
             [*ingest, "--dt", "0.1", "--min-duration", "5", "--sample-rate", "7.2"],
             setup=quantised_table),
        Case("table: --sample-rate -1", [*ingest, "--dt", "0.1", "--sample-rate", "-1"],
             setup=quantised_table),
        Case("identify: log sampled at 0.1 s, spec dt = 1.0", [*ident, "--method", "ls"],
             setup=retimed_log("0.1 s")),
        Case("identify: irregular 0.05-3 s time column", [*ident, "--method", "ls"],
             setup=retimed_log("jitter")),
        Case("identify: --dt-tolerance 5", [*ident, "--dt-tolerance", "5"], setup=base_log),
        Case("api: identify() on a log sampled at 0.1 s, spec dt = 1.0",
             setup=retimed_log("0.1 s"),
             python=API_SAMPLING.format(options="method='ls'", expect="--dt 1")),
        Case("api: identify() default (fallback chain) on an irregular time column",
             setup=retimed_log("jitter"),
             python=API_SAMPLING.format(options="", expect="irregular sampling")),
        Case("api: identify(dt_tolerance='loose')", setup=base_log,
             python=API_SAMPLING.format(options="method='ls', dt_tolerance='loose'",
                                        expect="dt_tolerance")),
        Case("api: identify(dt_tolerance=float('nan'))", setup=base_log,
             python=API_SAMPLING.format(options="method='ls', dt_tolerance=float('nan')",
                                        expect="tolerance")),
        Case("raw: ROS 1 bag garbage (.bag)", ["ingest", "x.bag", "--dt", "0.1", "--out",
                                               "x.csv"], setup=ros1_bag(False)),
        Case("raw: ROS 1 bag truncated half-way", ["ingest", "x.bag", "--dt", "0.1", "--out",
                                                   "x.csv"], expect="any", setup=ros1_bag(True),
             check=ingested_log_check),
        Case("raw: ingest NMEA without the [raw] extra (pynmea2 missing)",
             setup=real_nmea("RMC", "HDT"), python=MISSING_EXTRA),
        Case("raw: simulate --raw for heave (no surface vessel)",
             ["simulate", "--samples", "300", "--out", "h.csv", "--raw", "rawh"],
             check=no_files_check("h.csv", "h.json", "h.toml", "rawh")),
        Case("raw: simulate --raw an existing file",
             ["simulate", "--system", "cybership2", "--samples", "300", "--out", "h.csv",
              "--raw", "file"], setup=lambda d: (d / "file").write_text("x"),
             check=no_files_check("h.csv", "h.json", "h.toml")),
        Case("raw: sea-trial --raw an existing file",
             ["sea-trial", "--experiments", "2", "--samples", "2000", "--out", "st",
              "--raw", "file"], setup=lambda d: (d / "file").write_text("x"),
             check=no_files_check("st")),
        Case("raw: simulate --raw under a regular file",
             ["simulate", "--system", "cybership2", "--samples", "300", "--out", "h.csv",
              "--raw", "file/raw"], setup=lambda d: (d / "file").write_text("x"),
             check=no_files_check("h.csv", "h.json", "h.toml")),
        Case("path: ingest --out a directory", ["ingest", "raw", "--dt", "0.1", "--out",
                                                "dir.csv"],
             setup=lambda d: (raw_dir()(d), (d / "dir.csv").mkdir())),
        Case("path: ingest --out under a regular file", ["ingest", "raw", "--dt", "0.1",
                                                         "--out", "file/x.csv"],
             setup=lambda d: (raw_dir()(d), (d / "file").write_text("x"))),
        Case("path: identify --export into a directory", [*ident, "--export", "dir.csv"],
             setup=lambda d: (base_log(d), (d / "dir.csv").mkdir())),
        Case("path: identify --export under a regular file", [*ident, "--export", "file/m.toml"],
             setup=lambda d: (base_log(d), (d / "file").write_text("x"))),
    ]
    # -- paths
    c += [
        Case("path: simulate --out is a directory", ["simulate", "--out", "dir.csv"],
             setup=lambda d: (d / "dir.csv").mkdir()),
        Case("path: simulate --out under a regular file", ["simulate", "--out", "file/x.csv"],
             setup=lambda d: (d / "file").write_text("x")),
        Case("path: simulate --out in a read-only place", ["simulate", "--out", "RO"]),
        Case("path: simulate sidecar target is a directory (all-or-nothing)",
             ["simulate", "--samples", "200", "--out", "p.csv"], setup=partial_output_setup,
             check=partial_output_check),
        Case("path: identify --json into a directory", [*ident, "--json", "dir.csv"],
             setup=lambda d: (base_log(d), (d / "dir.csv").mkdir())),
        Case("path: identify --json under a regular file", [*ident, "--json", "file/x.json"],
             setup=lambda d: (base_log(d), (d / "file").write_text("x"))),
        Case("path: identify a missing log", ["identify", "missing.csv"]),
        Case("path: identify a directory", ["identify", "dir.csv"],
             setup=lambda d: (d / "dir.csv").mkdir()),
        Case("path: identify --model is a directory", [*ident, "--model", "dir.csv"],
             setup=lambda d: (base_log(d), (d / "dir.csv").mkdir())),
        Case("path: identify --model missing", [*ident, "--model", "nope.toml"],
             setup=base_log),
        Case("path: reproduce --out an existing file", ["reproduce", "--runs", "2",
                                                        "--samples", "50", "--out", "file"],
             setup=lambda d: (d / "file").write_text("x")),
        Case("path: reproduce --json into a directory", ["reproduce", "--runs", "2",
                                                         "--samples", "50", "--json",
                                                         "dir.csv"],
             setup=lambda d: (d / "dir.csv").mkdir()),
        Case("path: sea-trial --out an existing file", ["sea-trial", "--out", "file"],
             setup=lambda d: (d / "file").write_text("x")),
        Case("path: sea-trial --out under a regular file", ["sea-trial", "--out", "file/st"],
             setup=lambda d: (d / "file").write_text("x")),
        Case("path: simulate writes log, sidecar and spec together", ["simulate", "--samples",
                                                                      "300", "--out", "n.csv"],
             expect="ok", check=leftover_check({"n.csv", "n.json", "n.toml"})),
        Case("path: SIGKILL during a write leaves nothing after the next write",
             python="KILL"),
        Case("path: SIGTERM during a write removes its temporary files", python="TERM"),
    ]
    # -- logs
    c += [
        Case("log: CSV with two 'w' columns, no sidecar", ident,
             setup=edit_csv(lambda ls: [ls[0].replace("tau", "w"), *ls[1:]], sidecar=False)),
        Case("log: CSV with two 'w' columns, with sidecar", ident,
             setup=edit_csv(lambda ls: [ls[0].replace("tau", "w"), *ls[1:]])),
        Case("log: NaN in w", ident,
             setup=edit_csv(set_cell(10, "w", "nan"))),
        Case("log: inf in tau", ident,
             setup=edit_csv(set_cell(10, "tau", "inf"))),
        Case("log: text in a numeric column", ident,
             setup=edit_csv(set_cell(10, "w", "abc"))),
        Case("log: time not increasing", ident,
             setup=edit_csv(lambda ls: [*ls[:5], ls[6], ls[5], *ls[7:]])),
        Case("log: missing column tau", [*ident, "--model", "t.toml"],
             setup=edit_csv(lambda ls: [",".join(x.split(",")[:3] + x.split(",")[4:])
                                        for x in ls], sidecar=False)),
        Case("log: header only", ident, setup=edit_csv(lambda ls: ls[:1])),
        Case("log: empty file", ident, setup=edit_csv(lambda ls: [], sidecar=False)),
        Case("log: binary garbage .csv", ident,
             setup=lambda d: (base_log(d), (d / "t.csv").write_bytes(os.urandom(4000)))),
        Case("log: ragged rows", ident,
             setup=edit_csv(lambda ls: [*ls[:10], ls[10] + ",1,2,3", *ls[11:]])),
        Case("log: sidecar dtype not a string", ident,
             setup=edit_sidecar(lambda e: e["dtypes"].update(w=5))),
        Case("log: sidecar dtype unknown", ident,
             setup=edit_sidecar(lambda e: e["dtypes"].update(w="float77"))),
        Case("log: sidecar dtypes a list", ident,
             setup=edit_sidecar(lambda e: e.update(dtypes=["float64"]))),
        Case("log: sidecar columns a string", ident,
             setup=edit_sidecar(lambda e: e.update(columns="w"))),
        Case("log: sidecar metadata a list", ident,
             setup=edit_sidecar(lambda e: e.update(metadata=[1, 2]))),
        Case("log: sidecar seed a string", ident,
             setup=edit_sidecar(lambda e: e["metadata"].update(seed="zero"))),
        Case("log: sidecar spec wrong type", ident,
             setup=edit_sidecar(lambda e: e["metadata"].update(spec="heave"))),
        Case("log: sidecar spec states = 5", ident,
             setup=edit_sidecar(lambda e: e["metadata"]["spec"].update(states=5))),
        Case("log: sidecar invalid JSON", ident, setup=edit_sidecar(None, b"{not json")),
        Case("log: sidecar binary", ident, setup=edit_sidecar(None, b"\xff\xfe\x00\x01" * 50)),
        Case("log: sidecar a JSON list", ident, setup=edit_sidecar(None, b"[1, 2, 3]")),
        Case("log: sidecar NaN constant", ident,
             setup=edit_sidecar(lambda e: json.dumps(e).replace('"seed": 1', '"seed": NaN'))),
        Case("log: sidecar future format version", ident,
             setup=edit_sidecar(lambda e: e.update(format_version=99))),
        Case("log: Parquet corrupted pages (checksummed)", ["identify", "t.parquet"],
             setup=parquet_setup("corrupt-checksummed")),
        Case("log: Parquet corrupted pages (no checksums, huge values)",
             ["identify", "t.parquet"], setup=parquet_setup("corrupt-plain")),
        Case("log: Parquet truncated", ["identify", "t.parquet"],
             setup=parquet_setup("truncated")),
        Case("log: .parquet that is not Parquet", ["identify", "t.parquet"],
             setup=parquet_setup("not-parquet")),
        Case("log: Parquet with two 'w' columns", ["identify", "t.parquet"],
             setup=parquet_setup("duplicate-columns")),
        Case("log: Parquet metadata not JSON", ["identify", "t.parquet"],
             setup=parquet_setup("metadata-not-json")),
        Case("log: Parquet with inf", ["identify", "t.parquet"], setup=parquet_setup("inf-value")),
        Case("log: unsupported suffix", ["identify", "t.txt"],
             setup=lambda d: (d / "t.txt").write_text("a,b\n1,2\n")),
        Case("json: constant input in every experiment", [*ident, "--json", "-"],
             expect="any", setup=constant_input, check=strict_json_check),
        Case("json: constant signals in every experiment", [*ident, "--json", "-"],
             expect="any", setup=constant_everything, check=strict_json_check),
        *[Case(f"json: --method {m} --json is strict JSON", [*ident, "--method", m, "--json",
                                                            "-"], expect="ok", setup=base_log,
               check=strict_json_check) for m in OPEN_LOOP_METHODS],
        Case("closed loop: --method cl-iv on an open-loop log is refused (one line)",
             [*ident, "--method", "cl-iv"], setup=base_log),
        Case("json: --json file is strict JSON", [*ident, "--json", "r.json"], expect="ok",
             setup=base_log,
             check=lambda d, r: strict_json_check(d, subprocess.CompletedProcess(
                 [], 0, (d / "r.json").read_text(), ""))),
    ]
    # -- specs
    for name, text in [
        ("[theta0] w = 0.99", GOOD_SPEC + "[theta0]\nw = 0.99\n"),
        ("[equations] w = 5", 'states = ["w"]\ninputs = ["tau"]\n[equations]\nw = 5\n'),
        ("states = 5", 'states = 5\ninputs = ["tau"]\n[equations]\nw = ["w"]\n'),
        ("inputs = {a = 1}", 'states = ["w"]\ninputs = {a = 1}\n[equations]\nw = ["w"]\n'),
        ("theta0 strings", GOOD_SPEC + '[theta0]\nw = ["0.99", "-0.1", "1"]\n'),
        ("dt string", 'dt = "1.0"\n' + GOOD_SPEC),
        ("dt negative", "dt = -1.0\n" + GOOD_SPEC),
        ("dt inf", "dt = inf\n" + GOOD_SPEC),
        ("theta0 nan", GOOD_SPEC + "[theta0]\nw = [nan, 0.1, 1.0]\n"),
        ("theta0 wrong length", GOOD_SPEC + "[theta0]\nw = [0.9]\n"),
        ("theta0 a table of tables", GOOD_SPEC + "[theta0.w]\na = 1\n"),
        ("equations a list", 'states = ["w"]\ninputs = ["tau"]\nequations = ["w"]\n'),
        ("aggregate a number", GOOD_SPEC + "[aggregate]\nw = 3\n"),
        ("aggregate nonsense", GOOD_SPEC + '[aggregate]\nw = "w * w_c"\n'),
        ("unknown key", "colour = 1\n" + GOOD_SPEC),
        ("unknown signal", 'states = ["w"]\ninputs = ["tau"]\n[equations]\nw = ["q"]\n'),
        ("bad term", 'states = ["w"]\ninputs = ["tau"]\n[equations]\nw = ["w**3"]\n'),
        ("duplicate term", 'states = ["w"]\ninputs = ["tau"]\n[equations]\nw = ["w","w"]\n'),
        ("empty equation", 'states = ["w"]\ninputs = ["tau"]\n[equations]\nw = []\n'),
        ("no states", 'states = []\ninputs = ["tau"]\n[equations]\n'),
        ("state name not identifier", 'states = ["1w"]\n[equations]\n1w = ["1w"]\n'),
        ("invalid TOML", "states = [\n"),
        ("binary TOML", os.urandom(300)),
        ("UTF-16 TOML", GOOD_SPEC.encode("utf-16")),
        ("empty file", ""),
        ("name a table", "[name]\nx = 1\n" + GOOD_SPEC),
    ]:
        c.append(spec_case(name, text))
    # -- scale invariance and overflow
    for factor in (1e6, 1e-6):
        for method, combine in [(m, "pooled") for m in OPEN_LOOP_METHODS] + [
                (m, "stacked") for m in ("ls", "iv", "iv-zero-mean")]:
            model = "p.toml" if method in LIKELIHOOD_METHODS else "t.toml"
            c.append(Case(f"scale: all signals x{factor:g}, {method} {combine}",
                          ["identify", "s.csv", "--model", model, "--method", method,
                           "--combine", combine, "--json", "-"], expect="any",
                          setup=scaled(factor),
                          check=scale_check(factor, method, combine, model)))
    c.append(Case("scale: all signals x1e150 (overflow)", ["identify", "s.csv", "--model",
                                                          "t.toml", "--method", "ls"],
                  setup=scaled(1e150)))
    c.append(Case("scale: all signals x1e-170 (underflow)", ["identify", "s.csv", "--model",
                                                            "t.toml", "--method", "ls"],
                  setup=scaled(1e-170)))
    # -- environments
    for cls in ("HeaveEnv", "Manoeuvring3DOFEnv", "HeaveVectorEnv", "Manoeuvring3DOFVectorEnv"):
        vector = cls.endswith("VectorEnv")
        for kind in ("nan", "inf", "wrong-shape", "before-reset"):
            c.append(env_case(cls, kind, vector))
    return c


# ------------------------------------------------------------------------------ runner
def one_line_reason(stderr: str) -> bool:
    lines = [ln for ln in stderr.strip().splitlines() if ln.strip()]
    if not lines or "error:" not in lines[-1]:
        return False
    # one line, usage errors included (the CLI leaves out argparse's usage block)
    return len(lines) == 1


def run_case(case: Case, root: Path) -> Outcome:
    d = Path(tempfile.mkdtemp(prefix="case-", dir=root))
    t0 = time.perf_counter()
    try:
        if case.setup is not None:
            try:
                case.setup(d)
            except Exception as exc:
                return Outcome(case, "setup", f"setup failed: {exc!r:.200}",
                               time.perf_counter() - t0)
        if case.python in ("KILL", "TERM", "STREAM"):
            problem = {"KILL": killed_write, "TERM": terminated_write,
                       "STREAM": streamed_write}[case.python](d)
            verdict = "ok" if problem is None else (
                "traceback" if problem.startswith("traceback") else "silent")
            return Outcome(case, verdict, problem or "no temporary files remain",
                           time.perf_counter() - t0)
        if case.python is not None:
            t0 = time.perf_counter()
            r = subprocess.run([sys.executable, "-c", case.python], cwd=d, capture_output=True,
                               text=True, timeout=case.timeout,
                               env={**os.environ, "MPLBACKEND": "Agg"})
            dt = time.perf_counter() - t0
            last = (r.stdout.strip().splitlines() or [""])[-1]
            if TRACEBACK in r.stderr:
                return Outcome(case, "traceback", r.stderr.strip().splitlines()[-1], dt)
            if r.returncode == 0:
                return Outcome(case, "ok", last, dt)
            return Outcome(case, "silent", last or f"exit {r.returncode}", dt)
        argv = list(case.argv or [])
        if "RO" in argv:
            argv[argv.index("RO")] = readonly_dir(d)
        t0 = time.perf_counter()
        r = run_cli(argv, d, case.env, case.timeout)
        dt = time.perf_counter() - t0
    except subprocess.TimeoutExpired:
        return Outcome(case, "slow", "timed out", time.perf_counter() - t0)
    finally:
        pass
    err_last = (r.stderr.strip().splitlines() or [""])[-1]
    if TRACEBACK in r.stderr or r.returncode not in (0, 2):
        return Outcome(case, "traceback", f"exit {r.returncode}: {err_last}", dt)
    problem = case.check(d, r) if case.check is not None else None
    if problem:
        return Outcome(case, "silent", problem, dt)
    if case.expect in ("refuse", "fast-refuse"):
        if r.returncode != 2:
            return Outcome(case, "silent", "bad input accepted (exit 0)", dt)
        if not one_line_reason(r.stderr):
            return Outcome(case, "silent", f"no one-line reason: {r.stderr.strip()[:200]!r}", dt)
        if case.expect == "fast-refuse" and dt > REFUSE_SECONDS:
            return Outcome(case, "slow", f"refused after {dt:.1f} s: {err_last}", dt)
    elif case.expect == "ok" and r.returncode != 0:
        return Outcome(case, "silent", f"valid request failed: {err_last}", dt)
    if r.returncode == 2 and not one_line_reason(r.stderr):
        return Outcome(case, "silent", f"no one-line reason: {r.stderr.strip()[:200]!r}", dt)
    return Outcome(case, "ok", err_last if r.returncode else "exit 0", dt)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-k", default="", help="run only cases whose name contains this")
    parser.add_argument("--list", action="store_true")
    parser.add_argument("--keep", action="store_true", help="keep the scratch directories")
    parser.add_argument("--long", action="store_true",
                        help="also stream a 10^7-sample log to disk and check its peak memory")
    args = parser.parse_args(argv)
    selected = [c for c in cases(args.long) if args.k in c.name]
    if args.list:
        print("\n".join(c.name for c in selected))
        return 0
    root = Path(tempfile.mkdtemp(prefix="vesselid-hostile-"))
    counts = {"ok": 0, "traceback": 0, "silent": 0, "slow": 0, "setup": 0}
    sizes = {"refused": 0, "max_s": 0.0}
    failures = []
    try:
        for case in selected:
            out = run_case(case, root)
            counts[out.verdict] += 1
            if case.expect == "fast-refuse" and out.verdict == "ok":
                sizes["refused"] += 1
                sizes["max_s"] = max(sizes["max_s"], out.seconds)
            mark = "ok  " if out.verdict == "ok" else out.verdict.upper()
            print(f"{mark:9s} {out.seconds:6.1f}s  {case.name}  ->  {out.detail[:150]}",
                  flush=True)
            if out.verdict != "ok":
                failures.append(out)
    finally:
        if not args.keep:
            for p in root.glob("case-*/ro"):
                os.chmod(p, 0o755)
            shutil.rmtree(root, ignore_errors=True)
        for cache in _RAW_CACHE:
            shutil.rmtree(cache, ignore_errors=True)
    n_size = sum(c.expect == "fast-refuse" for c in selected)
    print()
    print(f"cases: {len(selected)}   ok: {counts['ok']}   tracebacks: {counts['traceback']}   "
          f"silent wrong answers: {counts['silent']}   slow refusals: {counts['slow']}   "
          f"setup failures: {counts['setup']}")
    print(f"absurd sizes refused in < {REFUSE_SECONDS:.0f} s: {sizes['refused']} of {n_size} "
          f"(slowest {sizes['max_s']:.1f} s)")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
