"""Raw sensor streams (simulate --raw) and `vesselid ingest`: round trip, bad input, CLI."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pymap3d  # noqa: F401  (a missing test dependency fails)
import pynmea2
import pytest

from vesselid.cli import main
from vesselid.data.ingest import IngestError, ingest
from vesselid.data.ingest.nmea import read_nmea
from vesselid.data.logs import TrialLog
from vesselid.data.nmea0183 import checksums, hex_checksums
from vesselid.data.rawexport import RawStreamConfig, write_raw_streams
from vesselid.plant.catalogue import get_system

SAMPLES = 3000


@pytest.fixture(scope="module")
def trial(tmp_path_factory):
    """A small CyberShip II log and its raw streams."""
    root = tmp_path_factory.mktemp("raw")
    sim = get_system("cybership2").simulate(SAMPLES, n_runs=2, seed=5)
    log = sim.to_log()
    manifest = write_raw_streams(log, root / "raw", seed=5)
    return log, root / "raw", manifest


def _aligned(ideal: TrialLog, got: TrialLog, gap: float) -> pd.DataFrame:
    """Join ingested rows to ideal rows by absolute sample index."""
    dt = ideal.spec.dt
    a = ideal.data.copy()
    per = math.ceil((SAMPLES * dt + gap) / dt)
    a["k"] = np.round(a["time"] / dt).astype(int) + a["experiment"] * per
    b = got.data.copy()
    b["k"] = np.round(b["time"] / dt).astype(int)
    return a.merge(b, on="k", suffixes=("_ideal", "_raw"))


def _decode(rows: np.ndarray) -> list[str]:
    return [bytes(r[r != 0]).decode("ascii") for r in rows]


def test_byte_matrix_formatting_equals_python_format():
    """The vectorised writer's fields equal Python's str.format and the list helpers."""
    from vesselid.data import nmea0183 as nmea

    rng = np.random.default_rng(0)
    v = np.concatenate([rng.normal(size=3000) * 10.0 ** rng.integers(-6, 10, 3000),
                        [0.0, -0.0, 0.5, 1.5, 2.5, 0.125, -0.004999, 9.9999999, 359.99999]])
    for d in (0, 1, 2, 4, 7):
        assert _decode(nmea.fixed_field(v, d)) == [f"{x:.{d}f}" for x in v]
    assert _decode(nmea.fixed_field(np.array([1.0, np.nan, -np.inf]), 2)) == ["1.00", "", ""]
    lat = rng.uniform(-89.9, 89.9, 500)
    lon = rng.uniform(-179.9, 179.9, 500)
    for new, old in ((nmea.latitude_fields(lat), nmea.format_latitude(lat)),
                     (nmea.longitude_fields(lon), nmea.format_longitude(lon))):
        assert _decode(new[0]) == old[0] and _decode(new[1]) == old[1]
    t = 1.78e9 + np.cumsum(rng.uniform(0, 5000, 500))
    assert _decode(nmea.utc_time_field(t)) == nmea.format_utc_time(t)
    assert _decode(nmea.utc_date_field(t)) == nmea.format_utc_date(t)
    fields = [nmea.fixed_field(v[:50], 2), nmea.const_field("T", 50), nmea.fixed_field(lat[:50], 1)]
    rows = nmea.sentence_rows("HE", "HDT", fields, t[:50])
    old = nmea.sentence_lines("HE", "HDT", [_decode(f) for f in fields], t[:50])
    assert _decode(rows) == [x + "\r\n" for x in old]


def test_sentences_parse_with_pynmea2_and_checksums_agree(trial):
    _log, raw, manifest = trial
    lines = (raw / "nav.nmea").read_text().splitlines()
    assert len(lines) == sum(manifest["sentences"].values())
    types = set()
    for line in lines[:: max(1, len(lines) // 400)]:
        tag, _, sentence = line.rpartition("\\")
        msg = pynmea2.parse(sentence, check=True)  # raises on a wrong checksum
        types.add(msg.sentence_type)
        body = sentence[1:sentence.index("*")]
        assert int(sentence[-2:], 16) == pynmea2.NMEASentence.checksum(body) == checksums([body])[0]
        assert tag.startswith("\\c:")
    assert {"GGA", "RMC", "HDT", "ROT", "VHW", "MWV"} <= types


def test_vectorised_parser_matches_pynmea2(trial):
    _log, raw, _ = trial
    streams, q = read_nmea(raw / "nav.nmea")
    assert q["bad_checksum"] == 0 and q["corrupt"] == 0 and q["clock_jumps"] == 0
    by = {s.name: s for s in streams if "RMC" not in s.source}  # lat/lon from GGA
    lines = (raw / "nav.nmea").read_text().splitlines()
    gga = [pynmea2.parse(x.rpartition("\\")[2]) for x in lines if "GGA," in x][:50]
    np.testing.assert_allclose(by["lat"].values[:50], [m.latitude for m in gga], atol=1e-12)
    np.testing.assert_allclose(by["lon"].values[:50], [m.longitude for m in gga], atol=1e-12)
    rot = [pynmea2.parse(x.rpartition("\\")[2]) for x in lines if "ROT," in x][:50]
    np.testing.assert_allclose(by["r"].values[:50],
                               [math.radians(float(m.rate_of_turn)) / 60 for m in rot], rtol=1e-12)


def test_round_trip_reproduces_the_ideal_log(trial):
    log, raw, _ = trial
    got = ingest(raw, 0.1)
    q = got.metadata["quality"]
    assert len(got.experiment_ids) == 2
    assert got.spec is not None and got.spec.states == log.spec.states
    m = _aligned(log, got, RawStreamConfig().experiment_gap)
    assert len(m) > 0.98 * len(log)
    for c in ("X", "Y", "N"):  # commands: exact, zero-order hold despite timestamp jitter
        np.testing.assert_array_equal(m[f"{c}_raw"], m[f"{c}_ideal"])
    noise = {"u": 0.005, "v": 0.005, "r": 0.002}  # the catalogue's sensor noise std
    for c, sd in noise.items():
        d = m[f"{c}_raw"] - m[f"{c}_ideal"]
        # same readings, re-encoded: differences far below the sensor noise except across
        # dropouts (interpolated) and from the compass noise in the rotation
        assert np.median(np.abs(d)) < 0.05 * sd, c
        assert np.std(d) < 0.25 * sd, c
    for col in ("psi", "u", "r", "north", "wind_speed"):
        assert col in got.data.columns
    assert 0 < q["columns"]["psi"]["interpolated_fraction"] < 0.05
    assert q["columns"]["psi"]["resampling"].startswith("anti-aliased")
    assert q["columns"]["X"]["resampling"] == "hold"


def _copy(raw: Path, dst: Path) -> Path:
    shutil.copytree(raw, dst)
    return dst


@pytest.mark.slow
def test_bad_sentences_are_counted(trial, tmp_path):
    _log, raw, _ = trial
    d = _copy(raw, tmp_path / "bad")
    lines = (d / "nav.nmea").read_text().splitlines()
    rng = np.random.default_rng(0)
    bad_cs = rng.choice(len(lines), 40, replace=False)
    for i in bad_cs:
        s = lines[i]
        lines[i] = s[:-2] + ("00" if s[-2:] != "00" else "11")
    lines.insert(100, "$GPGGA,garbage")
    lines.insert(200, "\x00\x01 random bytes")
    lines.insert(300, "$PSXN,1,2,3*00")
    # a second GNSS receiver with another talker id, at the same epochs
    extra = [x.replace("$GNRMC", "$GPRMC") for x in lines[1000:1200] if "$GNRMC" in x]
    extra = [x.rpartition("*")[0] for x in extra]
    extra = [f"{x}*{checksums([x[x.index('$') + 1:]])[0]:02X}" for x in extra]
    lines[1200:1200] = extra
    (d / "nav.nmea").write_text("\n".join(lines) + "\n")
    got = ingest(d, 0.1)
    src = got.metadata["quality"]["sources"][0]
    assert src["bad_checksum"] == 40
    assert src["corrupt"] >= 2
    assert src["talkers"]["RMC"]["GP"] == len(extra)
    assert src["ignored_talkers"]["RMC"] == len(extra)
    # read in small chunks (lines split across reads, a line longer than a chunk): the same
    import vesselid.data.ingest.nmea as nmea_reader

    with (d / "nav.nmea").open("a") as fh:
        fh.write("$GPGGA," + "9" * 9000 + "\n")
    whole = read_nmea(d / "nav.nmea")
    monkey = pytest.MonkeyPatch()
    monkey.setattr(nmea_reader, "CHUNK_BYTES", 997)
    try:
        chunked = read_nmea(d / "nav.nmea")
    finally:
        monkey.undo()
    assert chunked[1] == whole[1] and whole[1]["corrupt"] == src["corrupt"] + 1
    for a, b in zip(whole[0], chunked[0], strict=True):
        np.testing.assert_array_equal(a.values, b.values)
        np.testing.assert_array_equal(a.t, b.t)


def test_logger_clock_jump_is_absorbed_and_counted(trial, tmp_path):
    _log, raw, _ = trial
    d = _copy(raw, tmp_path / "jump")
    text = (d / "nav.nmea").read_text().splitlines()
    half = len(text) // 3
    tail = text[half:]
    # the logger clock jumps 37 s ahead: rewrite the TAG blocks (with valid checksums)
    tags = [f"c:{int(x[3:x.index('*')]) + 37_000}" for x in tail]
    sentences = [x[x.index("$"):] for x in tail]
    out = text[:half] + [f"\\{t}*{c}\\{s}" for t, c, s in
                         zip(tags, hex_checksums(tags), sentences, strict=True)]
    (d / "nav.nmea").write_text("\n".join(out) + "\n")
    ref = ingest(raw, 0.1)
    got = ingest(d, 0.1)
    assert got.metadata["quality"]["sources"][0]["clock_jumps"] == 1
    pd.testing.assert_frame_equal(got.data[["u", "v", "X"]], ref.data[["u", "v", "X"]],
                                  atol=1e-3, rtol=0)  # jitter medians differ


def test_sensor_missing_for_minutes_splits_the_experiment(trial, tmp_path):
    _log, raw, _ = trial
    d = _copy(raw, tmp_path / "outage")
    lines = (d / "nav.nmea").read_text().splitlines()
    ms = np.array([int(x[3:x.index("*")]) for x in lines]) / 1000
    t0 = ms[0]
    out = [x for x, t in zip(lines, ms, strict=True)
           if not ("HDT," in x and t0 + 100 < t < t0 + 220)]
    (d / "nav.nmea").write_text("\n".join(out) + "\n")
    got = ingest(d, 0.1)
    assert len(got.experiment_ids) == 3
    assert got.metadata["quality"]["columns"]["psi"]["longest_gap_s"] > 100


def test_refusals_are_one_line_exit_2(trial, tmp_path, capsys):
    _log, raw, _ = trial
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["ingest", str(empty), "--dt", "0.1", "--out", str(tmp_path / "t.csv")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "error:" in err
    junk = tmp_path / "junk.nmea"
    junk.write_bytes(b"\xff\xfe not nmea at all\n$GPGGA,1,2*ZZ\n")
    assert main(["ingest", str(junk), "--dt", "0.1", "--out", str(tmp_path / "t.csv")]) == 2
    assert "no valid NMEA 0183" in capsys.readouterr().err
    only_hdt = tmp_path / "hdt.nmea"
    only_hdt.write_text("\n".join(x for x in (raw / "nav.nmea").read_text().splitlines()
                                  if "HDT," in x) + "\n")
    with pytest.raises(IngestError, match="no velocity"):
        ingest(only_hdt, 0.1)
    with pytest.raises(IngestError, match="dt"):
        ingest(raw, -1.0)


def test_cli_simulate_raw_then_ingest(tmp_path, capsys):
    raw = tmp_path / "raw"
    assert main(["simulate", "--system", "cybership2", "--samples", "1500", "--seed", "2",
                 "--out", str(tmp_path / "ideal.csv"), "--raw", str(raw)]) == 0
    assert (raw / "cybership2.toml").is_file() and (raw / "actuators.csv").is_file()
    out = tmp_path / "trial.csv"
    assert main(["ingest", str(raw), "--dt", "0.1", "--out", str(out)]) == 0
    log = TrialLog.load(out, spec=None)
    assert log.metadata["quality"]["rows"] == len(log)
    assert "next: vesselid identify" in capsys.readouterr().out


def test_mapped_csv_with_units_and_angles(tmp_path):
    t = 1.78e9 + np.arange(0, 120, 0.05)
    psi = 0.3 * np.sin(0.05 * (t - t[0])) + 3.1
    u = 0.5 + 0.0 * t
    frame = pd.DataFrame({"ts_ms": (t * 1000).astype(np.int64),
                          "hdg_deg": np.degrees(np.mod(psi, 2 * np.pi)),
                          "vn": u * np.cos(psi), "ve": u * np.sin(psi), "gyro": 0.0 * t})
    frame.to_csv(tmp_path / "nav.csv", index=False)
    (tmp_path / "ingest.toml").write_text(
        '[[csv]]\nfile = "nav.csv"\ntime = "ts_ms"\ntime_unit = "ms"\n'
        'columns = { psi = { column = "hdg_deg", scale = 0.017453292519943295 }, '
        'vel_north = "vn", vel_east = "ve", r = "gyro" }\n')
    got = ingest(tmp_path, 0.1, min_duration=10)
    np.testing.assert_allclose(got.data["u"], 0.5, atol=1e-6)
    np.testing.assert_allclose(got.data["v"], 0.0, atol=1e-6)
    assert np.ptp(got.data["psi"]) < 1.0  # unwrapped across ±π
    assert got.metadata["quality"]["columns"]["psi"]["resampling"].startswith("anti-aliased")
