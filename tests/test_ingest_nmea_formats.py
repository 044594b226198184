"""NMEA 0183 as real vessels send it: HDG/HDM, ZDA, ROT, RSA, RPM, XDR, heading offset,
lever arm, refusals that name the missing channel and why, quantised table time columns,
missing optional packages."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from vesselid.cli import main
from vesselid.data.ingest import IngestError, ingest, summary
from vesselid.data.nmea0183 import KNOT, sentence_lines

T0 = 1_780_308_000.0  # the synthetic log starts on 1 June 2026 at ten o'clock
LAT0, LON0 = 63.43, 10.39
M_PER_DEG = 111_320.0


def _hhmmss(t: np.ndarray) -> list[str]:
    tod = np.mod(t, 86400.0)
    return [f"{int(x // 3600):02d}{int(x // 60 % 60):02d}{x % 60:05.2f}" for x in tod]


def _latlon(north: np.ndarray, east: np.ndarray) -> tuple[list[str], ...]:
    lat = LAT0 + north / M_PER_DEG
    lon = LON0 + east / (M_PER_DEG * math.cos(math.radians(LAT0)))
    la = [f"{int(x):02d}{(x - int(x)) * 60:010.7f}" for x in lat]
    lo = [f"{int(x):03d}{(x - int(x)) * 60:010.7f}" for x in lon]
    return la, ["N"] * lat.size, lo, ["E"] * lon.size


def _rmc(t, north, east, sog_kn, cog_deg, date=True, var=None):
    n = t.size
    var_f = [f"{abs(var):.1f}"] * n if var is not None else [""] * n
    var_d = [("E" if var >= 0 else "W")] * n if var is not None else [""] * n
    return sentence_lines("GP", "RMC", [
        _hhmmss(t), ["A"] * n, *_latlon(north, east), [f"{x:.3f}" for x in sog_kn],
        [f"{x:.3f}" for x in np.mod(cog_deg, 360)], ["010626" if date else ""] * n,
        var_f, var_d, ["A"] * n])


def _interleave(*groups: list[str]) -> str:
    return "\n".join(x for row in zip(*groups, strict=True) for x in row) + "\n"


def _track(n=400, rate=1.0, u=3.0, r=0.0, psi0=0.5, x=0.0, y=0.0):
    """Reference point moving at surge u, sway 0, yaw rate r; the antenna at (x, y)."""
    t = T0 + np.arange(n) / rate
    s = t - T0
    psi = psi0 + r * s
    if r:
        north = u / r * (np.sin(psi) - math.sin(psi0))
        east = -u / r * (np.cos(psi) - math.cos(psi0))
    else:
        north, east = u * s * math.cos(psi0), u * s * math.sin(psi0)
    an = north + np.cos(psi) * x - np.sin(psi) * y
    ae = east + np.sin(psi) * x + np.cos(psi) * y
    vn = u * np.cos(psi) + r * (-np.sin(psi) * x - np.cos(psi) * y)
    ve = u * np.sin(psi) + r * (np.cos(psi) * x - np.sin(psi) * y)
    sog = np.hypot(vn, ve) / KNOT
    cog = np.degrees(np.arctan2(ve, vn))
    return t, psi, an, ae, sog, cog


def _write(d: Path, text: str, toml: str | None = None) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    (d / "nav.nmea").write_text(text)
    if toml is not None:
        (d / "ingest.toml").write_text(toml)
    return d


# --------------------------------------------------------------------------- HDG / HDM
def test_hdg_whole_degrees_with_variation_in_the_sentence(tmp_path):
    t, psi, n, e, sog, cog = _track()
    mag = np.round(np.degrees(psi) - (-3.0) - 1.0)  # true = mag + dev(+1 E) + var(-3 W)
    hdg = sentence_lines("HC", "HDG", [[f"{x:.0f}" for x in mag], ["1.0"] * t.size,
                                       ["E"] * t.size, ["3.0"] * t.size, ["W"] * t.size])
    vhw = sentence_lines("VW", "VHW", [[""] * t.size, ["T"] * t.size, [""] * t.size,
                                       ["M"] * t.size, ["5.8"] * t.size, ["N"] * t.size,
                                       [""] * t.size, ["K"] * t.size])
    d = _write(tmp_path / "yacht", _interleave(_rmc(t, n, e, sog, cog), hdg, vhw))
    log = ingest(d, 1.0, min_duration=10)
    got = np.degrees(log.data["psi"].to_numpy())
    want = mag + 1.0 - 3.0
    np.testing.assert_allclose(np.mod(got[:50], 360), np.mod(want[:50], 360), atol=1e-9)
    c = log.metadata["quality"]["columns"]["psi"]
    assert c["quantisation_deg"] == 1.0 and c["magnetic"]
    assert c["variation_from"] == {"sentence": t.size}
    text = summary(log)
    assert "quantised to 1 deg" in text and "magnetic" in text
    # surge from SOG rotated with a 1-degree quantised heading: within cos(0.5 deg)
    np.testing.assert_allclose(log.data["u"], 3.0, rtol=2e-4, atol=0)


def test_hdg_without_variation_is_refused_naming_the_setting_then_uses_it(tmp_path):
    t, psi, n, e, sog, cog = _track()
    hdg = sentence_lines("HC", "HDG", [[f"{x:.5f}" for x in np.degrees(psi) - 2.0]])
    d = _write(tmp_path / "y", _interleave(_rmc(t, n, e, sog, cog), hdg))
    with pytest.raises(IngestError, match=r"no heading .*HDG.*magnetic_variation"):
        ingest(d, 1.0, min_duration=10)
    (d / "ingest.toml").write_text("[nmea]\nmagnetic_variation = 2.0\n")
    log = ingest(d, 1.0, min_duration=10)
    np.testing.assert_allclose(log.data["psi"].iloc[:20], psi[:20], atol=1e-6)
    np.testing.assert_allclose(log.data["v"], 0.0, atol=2e-3)
    assert log.metadata["quality"]["columns"]["psi"]["variation_from"] == \
        {"configuration": t.size}


def test_hdm_takes_the_rmc_variation(tmp_path):
    t, psi, n, e, sog, cog = _track()
    hdm = sentence_lines("HC", "HDM", [[f"{x:.2f}" for x in np.degrees(psi) + 4.5],
                                       ["M"] * t.size])
    d = _write(tmp_path / "y", _interleave(_rmc(t, n, e, sog, cog, var=-4.5), hdm))
    log = ingest(d, 1.0, min_duration=10)
    np.testing.assert_allclose(log.data["psi"].iloc[:20], psi[:20], atol=1e-4)
    assert log.metadata["quality"]["columns"]["psi"]["variation_from"] == {"RMC": t.size}


def test_hdt_wins_over_hdg(tmp_path):
    t, psi, n, e, sog, cog = _track()
    hdt = sentence_lines("HE", "HDT", [[f"{x:.2f}" for x in np.degrees(psi)], ["T"] * t.size])
    hdg = sentence_lines("HC", "HDG", [["0"] * t.size, [""] * t.size, [""] * t.size,
                                       ["0"] * t.size, ["E"] * t.size])
    d = _write(tmp_path / "y", _interleave(_rmc(t, n, e, sog, cog), hdt, hdg))
    log = ingest(d, 1.0, min_duration=10)
    assert "HDT" in log.metadata["quality"]["columns"]["psi"]["source"]


# --------------------------------------------------------------------------- time sources
def _vtg(sog, cog):
    k = sog.size
    return sentence_lines("GP", "VTG", [[f"{x:.3f}" for x in np.mod(cog, 360)], ["T"] * k,
                                        [""] * k, ["M"] * k, [f"{x:.3f}" for x in sog],
                                        ["N"] * k, [""] * k, ["K"] * k, ["A"] * k])


def _zda(t, date=True):
    k = t.size
    if date:
        return sentence_lines("GP", "ZDA", [_hhmmss(t), ["01"] * k, ["06"] * k, ["2026"] * k,
                                            ["00"] * k, ["00"] * k])
    return sentence_lines("GP", "ZDA", [_hhmmss(t), [""] * k, [""] * k, [""] * k,
                                        ["00"] * k, [""] * k])


@pytest.mark.parametrize("date", [True, False])
def test_zda_is_a_time_source(tmp_path, date):
    t, psi, _n, _e, sog, cog = _track(rate=1.0)
    hdt = sentence_lines("HE", "HDT", [[f"{x:.2f}" for x in np.degrees(psi)], ["T"] * t.size])
    d = _write(tmp_path / "z", _interleave(_zda(t, date), _vtg(sog, cog), hdt))
    log = ingest(d, 1.0, min_duration=10)
    assert len(log) == t.size and len(log.experiment_ids) == 1
    np.testing.assert_allclose(log.data["u"], 3.0, rtol=1e-4)
    if date:
        assert log.metadata["time_origin_utc"].startswith("2026-06-01T10:00:00")


def test_untimed_sentences_between_fixes_are_spread_and_counted(tmp_path):
    t, _psi, _n, _e, sog, cog = _track(n=200, rate=1.0)
    # HDT at 4 Hz between 1 Hz ZDA/VTG: 4 sentences share each fix time
    t4 = T0 + np.arange(4 * t.size) / 4.0
    psi4 = 0.5 + 0.0 * t4
    hdt = sentence_lines("HE", "HDT", [[f"{x:.2f}" for x in np.degrees(psi4)],
                                       ["T"] * t4.size])
    lines = []
    zda, vtg = _zda(t), _vtg(sog, cog)
    for i in range(t.size):
        lines += [zda[i], vtg[i], *hdt[4 * i:4 * i + 4]]
    d = _write(tmp_path / "z", "\n".join(lines) + "\n")
    log = ingest(d, 0.25, min_duration=10)
    c = log.metadata["quality"]["columns"]["psi"]
    assert c["samples"] == t4.size and c["time_interpolated"] == 3 * t.size
    assert c.get("duplicate_times", 0) == 0
    assert abs(c["rate_hz"] - 4.0) < 1e-9
    assert "sample times interpolated between fixes" in summary(log)


def test_no_time_source_is_named(tmp_path):
    t, psi, _n, _e, sog, cog = _track()
    hdt = sentence_lines("HE", "HDT", [[f"{x:.2f}" for x in np.degrees(psi)], ["T"] * t.size])
    d = _write(tmp_path / "z", _interleave(_vtg(sog, cog), hdt))
    with pytest.raises(IngestError, match=r"no time source: found no RMC/GGA/ZDA/GLL sentences "
                                          r"with a time.*400 VTG, 400 HDT"):
        ingest(d, 1.0)
    empty = sentence_lines("GP", "ZDA", [[""] * t.size, [""] * t.size, [""] * t.size,
                                         [""] * t.size])
    d = _write(tmp_path / "z2", _interleave(empty, _vtg(sog, cog)))
    with pytest.raises(IngestError, match=r"no time source: 400 ZDA but none with a valid time"):
        ingest(d, 1.0)


def test_empty_heading_fields_are_named(tmp_path):
    t, _psi, _n, _e, sog, cog = _track()
    hdt = sentence_lines("II", "HDT", [[""] * t.size, ["T"] * t.size])
    d = _write(tmp_path / "z", _interleave(_zda(t), _vtg(sog, cog), hdt))
    with pytest.raises(IngestError, match=r"no heading .*400 HDT sentence\(s\), none with a "
                                          r"valid value"):
        ingest(d, 1.0)


def test_no_velocity_names_what_was_found(tmp_path):
    t, psi, *_ = _track()
    hdt = sentence_lines("HE", "HDT", [[f"{x:.2f}" for x in np.degrees(psi)], ["T"] * t.size])
    vhw = sentence_lines("VW", "VHW", [[""] * t.size, ["T"] * t.size, [""] * t.size,
                                       ["M"] * t.size, ["5.8"] * t.size, ["N"] * t.size,
                                       [""] * t.size, ["K"] * t.size])
    d = _write(tmp_path / "z", _interleave(_zda(t), hdt, vhw))
    with pytest.raises(IngestError, match=r"no velocity: .*no RMC/VTG sentences \(channels "
                                          r"found: \['psi', 'u_log'\]; sentences: .*ZDA"):
        ingest(d, 1.0)


# ---------------------------------------------------- ROT, RSA, RPM, XDR; offset, lever arm
def test_rot_rsa_rpm_xdr_channels(tmp_path):
    t, psi, n, e, sog, cog = _track(r=0.01, u=2.0)
    k = t.size
    delta = 10.0 * np.sin(0.05 * np.arange(k))
    rpm = 600 + 100 * np.cos(0.03 * np.arange(k))
    hdt = sentence_lines("HE", "HDT", [[f"{x:.3f}" for x in np.degrees(psi)], ["T"] * k])
    rot = sentence_lines("TI", "ROT", [[f"{math.degrees(0.01) * 60:.3f}"] * k, ["A"] * k])
    rsa = sentence_lines("AG", "RSA", [[f"{x:.2f}" for x in delta], ["A"] * k, [""] * k,
                                       [""] * k])
    rpm_s = sentence_lines("ER", "RPM", [["S"] * k, ["1"] * k, [f"{x:.1f}" for x in rpm],
                                         ["80"] * k, ["A"] * k])
    xdr = sentence_lines("YX", "XDR", [["A"] * k, [f"{x:.2f}" for x in -delta], ["D"] * k,
                                       ["RUDDER"] * k, ["C"] * k, ["12.5"] * k, ["C"] * k,
                                       ["AIRTEMP"] * k])
    toml = ('[nmea]\nchannels = { rudder = "delta", shaft_rpm = { name = "n", scale = '
            f'{1 / 60!r} }} }}\nxdr = {{ RUDDER = "delta_xdr" }}\n')
    d = _write(tmp_path / "z", _interleave(_rmc(t, n, e, sog, cog), hdt, rot, rsa, rpm_s, xdr),
               toml)
    log = ingest(d, 1.0, min_duration=10)
    data = log.data
    np.testing.assert_allclose(data["r"], 0.01, rtol=1e-4)
    np.testing.assert_allclose(data["delta"], np.radians(delta), atol=1e-4)  # 0.01 deg
    np.testing.assert_allclose(data["delta_xdr"], -np.radians(delta), atol=1e-4)
    np.testing.assert_allclose(data["n"], rpm / 60, atol=1e-3)
    src = log.metadata["quality"]["sources"][0]
    assert src["xdr_unmapped"] == {"AIRTEMP": k}
    text = summary(log)
    assert "AIRTEMP" in text and "from NMEA channel 'rudder'" in text


def test_heading_offset_of_a_dual_antenna_baseline(tmp_path):
    t, psi, n, e, sog, cog = _track(u=2.0, psi0=0.3)
    hdt = sentence_lines("GN", "HDT", [[f"{x:.3f}" for x in np.mod(np.degrees(psi) + 68.0,
                                                                     360)], ["T"] * t.size])
    d = _write(tmp_path / "usv", _interleave(_rmc(t, n, e, sog, cog), hdt))
    raw = ingest(d, 1.0, min_duration=10)
    # without the offset: the track is 68 degrees off the heading (a large sway)
    assert abs(np.median(raw.data["v"]) + 2.0 * math.sin(math.radians(68))) < 1e-3
    (d / "ingest.toml").write_text("heading_offset = 68.0\n")
    log = ingest(d, 1.0, min_duration=10)
    np.testing.assert_allclose(log.data["v"], 0.0, atol=1e-3)
    np.testing.assert_allclose(log.data["u"], 2.0, atol=1e-3)
    np.testing.assert_allclose(log.data["psi"].iloc[0], 0.3, atol=1e-4)
    assert "heading offset 68 deg removed" in summary(log)


def test_lever_arm_moves_position_and_velocity_to_the_reference_point(tmp_path):
    x, y = 3.0, -0.8
    t, psi, n, e, sog, cog = _track(u=2.0, r=0.02, x=x, y=y, n=300)
    hdt = sentence_lines("GN", "HDT", [[f"{v:.4f}" for v in np.mod(np.degrees(psi), 360)],
                                       ["T"] * t.size])
    rot = sentence_lines("TI", "ROT", [[f"{math.degrees(0.02) * 60:.4f}"] * t.size,
                                       ["A"] * t.size])
    d = _write(tmp_path / "turn", _interleave(_rmc(t, n, e, sog, cog), hdt, rot),
               f"lever_arm = [{x}, {y}]\norigin = [{LAT0}, {LON0}]\n")
    log = ingest(d, 1.0, min_duration=10)
    # the reference point moves at u = 2, v = 0 on a circle of radius u/r through the origin
    np.testing.assert_allclose(log.data["u"], 2.0, atol=2e-3)
    np.testing.assert_allclose(log.data["v"], 0.0, atol=2e-3)
    (d / "ingest.toml").write_text(f"origin = [{LAT0}, {LON0}]\n")
    raw = ingest(d, 1.0, min_duration=10)
    np.testing.assert_allclose(raw.data["v"], 0.02 * x, atol=2e-3)  # v_antenna = r x
    p = raw.data["psi"]
    np.testing.assert_allclose(raw.data["north"] - log.data["north"],
                               np.cos(p) * x - np.sin(p) * y, atol=1e-9)
    np.testing.assert_allclose(raw.data["east"] - log.data["east"],
                               np.sin(p) * x + np.cos(p) * y, atol=1e-9)
    assert "lever arm [3.0, -0.8, 0.0] m applied to north/east, u/v" in summary(log)


@pytest.mark.parametrize("toml, match", [
    ("lever_arm = [1.0]\n", "lever_arm must be"),
    ("heading_offset = 'a'\n", "heading_offset must be a number"),
    ("[nmea]\nmagnetic_variation = 400\n", "within ±180"),
    ("[nmea]\nxdr = { R = 3 }\n", "nmea.xdr.R must be a channel name"),
    ("[nmea]\ncolour = 1\n", "unknown \\[nmea\\] keys"),
])
def test_bad_settings_are_refused(tmp_path, toml, match):
    t, _psi, n, e, sog, cog = _track(n=50)
    d = _write(tmp_path / "b", _interleave(_rmc(t, n, e, sog, cog)), toml)
    with pytest.raises(IngestError, match=match):
        ingest(d, 1.0)


# ------------------------------------------------------------------- quantised time column
def _quantised_table(d: Path, rate=7.39, n=3000):
    d.mkdir(parents=True, exist_ok=True)
    k = np.arange(n)
    t = 100.0 + k / rate
    tq = np.array([float(f"{x:.3g}") for x in t])
    u = 1.0 + 0.2 * np.sin(0.01 * k)
    lines = ["time,u,v,r,psi"] + [f"{a:.6g},{b:.9f},0.0,0.01,{0.01 * i / rate:.9f}"
                                  for i, (a, b) in enumerate(zip(tq, u, strict=True))]
    (d / "tank.csv").write_text("\n".join(lines) + "\n")
    (d / "ingest.toml").write_text(
        '[[csv]]\nfile = "tank.csv"\ncolumns = { u = "u", v = "v", r = "r", psi = "psi" }\n')
    return t, u


def test_quantised_time_column_is_refused_then_rebuilt(tmp_path):
    t, u = _quantised_table(tmp_path / "q")
    with pytest.raises(IngestError, match=r"repeats \d+ of 3000 timestamps.*--sample-rate"):
        ingest(tmp_path / "q", 0.1, min_duration=5)
    with pytest.raises(IngestError, match=r"7\.2 Hz does not fit the time column.*about 7\.3"):
        ingest(tmp_path / "q", 0.1, min_duration=5, sample_rate=7.2)
    log = ingest(tmp_path / "q", 0.1, min_duration=5, sample_rate=7.39)
    src = log.metadata["quality"]["sources"][0]
    assert src["time_rebuilt"]["sample_rate_hz"] == 7.39 and src["rows"] == 3000
    c = log.metadata["quality"]["columns"]["u"]
    assert c["samples"] == 3000 and abs(c["rate_hz"] - 7.39) < 1e-6
    assert "duplicate_times" not in c and len(log.experiment_ids) == 1
    # every row kept: the log spans the table (3000 rows at 7.39 Hz)
    assert abs(log.data["time"].iloc[-1] - 2999 / 7.39) < 0.2
    got = np.interp(t[:1000] - t[0], log.data["time"], log.data["u"])
    assert np.max(np.abs(got - u[:1000])) < 0.01  # re-timed within the rounding error
    assert "time axis rebuilt at 7.39 Hz" in summary(log)


def test_cli_quantised_table_exit_2_and_sample_rate_option(tmp_path, capsys):
    _quantised_table(tmp_path / "q")
    out = str(tmp_path / "x.csv")
    assert main(["ingest", str(tmp_path / "q"), "--dt", "0.1", "--min-duration", "5",
                 "--out", out]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--sample-rate" in err
    assert main(["ingest", str(tmp_path / "q"), "--dt", "0.1", "--min-duration", "5",
                 "--sample-rate", "7.39", "--out", out]) == 0
    assert "time axis rebuilt" in capsys.readouterr().out


# -------------------------------------------------------------------- optional packages
def test_missing_extra_names_it(tmp_path, monkeypatch, capsys):
    import sys

    t, _psi, n, e, sog, cog = _track(n=50)
    d = _write(tmp_path / "m", _interleave(_rmc(t, n, e, sog, cog)))
    monkeypatch.setitem(sys.modules, "pynmea2", None)  # import pynmea2 -> ImportError
    assert main(["ingest", str(d), "--dt", "1", "--out", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "'pynmea2'" in err and "pip install 'vesselid[raw]'" in err
