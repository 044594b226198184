"""Run ``vesselid ingest`` on real NMEA 0183 recordings and print what happened.

Real logs are not shipped with the package (their licences vary); point the script at
files or directories you have, e.g. the sample logs of the Signal K server (Apache-2.0,
``samples/*.log`` of github.com/SignalK/signalk-server: a sailing yacht with VTG/VHW/ZDA/
GLL/MWV and empty heading fields, a boat with HDG/HDM but no time source, a GNSS receiver
with GGA/RMC/VTG and no heading)::

    python scripts/check_real_nmea.py ~/signalk-server/samples --dt 1
    VESSELID_REAL_NMEA=~/logs python scripts/check_real_nmea.py

Each file is ingested on its own (with the ``ingest.toml`` beside it, if any) in a
scratch directory; the script prints, per file, the sentence counts, the exit code and
either the console summary or the one-line refusal, and at the end the counts of
ingested / refused / crashed files. A crash (a traceback, an exit code other than 0 and
2) makes the script exit 1. With no path and no ``VESSELID_REAL_NMEA`` it says so and
exits 0 (nothing to check).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from collections import Counter
from pathlib import Path

SUFFIXES = (".nmea", ".txt", ".log", ".0183", ".n0183")


def sentence_counts(path: Path, limit: int = 2_000_000) -> Counter:
    """Formatter counts of the first ``limit`` lines (``$GPRMC`` → ``RMC``)."""
    counts: Counter = Counter()
    with open(path, "rb") as fh:
        for k, line in enumerate(fh):
            if k >= limit:
                break
            i = max(line.find(b"$"), line.find(b"!"))
            if i >= 0 and len(line) > i + 6:
                counts[line[i + 3:i + 6].decode("ascii", "replace")] += 1
    return counts


def files_under(paths: list[str]) -> list[Path]:
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            out += sorted(f for f in p.rglob("*") if f.suffix.lower() in SUFFIXES)
        elif p.is_file():
            out.append(p)
    return out


def check(path: Path, dt: float, extra: list[str]) -> tuple[str, str]:
    """Ingest one file; (``ingested``/``refused``/``crashed``, what it printed)."""
    with tempfile.TemporaryDirectory(prefix="vesselid-real-") as tmp:
        d = Path(tmp) / "in"
        d.mkdir()
        shutil.copy(path, d / (path.stem + ".nmea"))
        cfg = path.parent / "ingest.toml"
        if cfg.is_file():
            shutil.copy(cfg, d / "ingest.toml")
        r = subprocess.run([sys.executable, "-m", "vesselid", "ingest", str(d), "--dt", str(dt),
                            "--out", str(Path(tmp) / "out.csv"), *extra],
                           capture_output=True, text=True, timeout=600)
    if "Traceback (most recent call last)" in r.stderr or r.returncode not in (0, 2):
        return "crashed", f"exit {r.returncode}: {r.stderr.strip()[-2000:]}"
    if r.returncode == 2:
        return "refused", r.stderr.strip()
    return "ingested", r.stdout.strip()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paths", nargs="*", help="NMEA files or directories "
                                                 "(default: $VESSELID_REAL_NMEA)")
    parser.add_argument("--dt", type=float, default=1.0, help="ingest --dt (s)")
    parser.add_argument("--min-duration", type=float, default=10.0)
    args = parser.parse_args(argv)
    paths = args.paths or ([os.environ["VESSELID_REAL_NMEA"]]
                           if os.environ.get("VESSELID_REAL_NMEA") else [])
    files = files_under(paths)
    if not files:
        print("no real NMEA recordings given (pass paths or set VESSELID_REAL_NMEA); "
              "nothing checked")
        return 0
    tally: Counter = Counter()
    for f in files:
        counts = sentence_counts(f)
        top = ", ".join(f"{n} {k}" for k, n in counts.most_common(12))
        verdict, text = check(f, args.dt, ["--min-duration", str(args.min_duration)])
        tally[verdict] += 1
        print(f"== {f} ({f.stat().st_size / 1e3:.0f} kB; {top})")
        print(f"   {verdict.upper()}")
        for line in text.splitlines():
            print(f"   {line}")
    print(f"\nfiles: {len(files)}   ingested: {tally['ingested']}   refused with a reason: "
          f"{tally['refused']}   crashed: {tally['crashed']}")
    return 1 if tally["crashed"] else 0


if __name__ == "__main__":
    sys.exit(main())
