"""Trial logs: one row per sample, with metadata that travels with the data.

A :class:`TrialLog` wraps a :class:`pandas.DataFrame` whose columns are (docs/architecture.md,
"Trial log"):

* ``experiment`` (optional): experiment id; one experiment (id ``0``) when absent,
* ``time`` (optional): sample time, strictly increasing within every experiment,
* one column per state and input of the model spec,
* measured disturbance (sensor) columns used by aggregate relations, e.g. ``w_c``,
* ground truth ``true_<name>`` columns when the log was simulated,

plus a JSON-serialisable ``metadata`` dict (``"spec"``, ``"seed"``, ``"vesselid_version"``,
noise settings, ...).  On disk the metadata lives in a JSON sidecar next to a CSV file
(``trial.csv`` → ``trial.json``) or inside the schema metadata of a Parquet file
(key ``b"vesselid"``).  Saving is atomic and the round trip is exact: floats are written
in their shortest round-trip text (``repr``: ``0.1``, not ``0.10000000000000001``) and
read back with a correctly rounding parser, and column dtypes are recorded so that
``TrialLog.load(p).data`` equals the saved frame.

The row index is not saved; a loaded log always has a default ``RangeIndex``.
"""

from __future__ import annotations

import contextlib
import csv
import functools
import json
import math
import re
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from vesselid.core.fileio import atomic_group, finite_or_none
from vesselid.errors import LogValidationError, ModelSpecError
from vesselid.model.spec import ModelSpec

__all__ = [
    "PARQUET_METADATA_KEY",
    "SUPPORTED_SUFFIXES",
    "TRUTH_PREFIX",
    "TrialLog",
    "TrialLogWriter",
    "concat_logs",
    "estimate_shape",
]

#: Key of the vesselid metadata in the Parquet schema metadata.
PARQUET_METADATA_KEY = b"vesselid"
#: File suffixes :meth:`TrialLog.save` and :meth:`TrialLog.load` understand.
SUPPORTED_SUFFIXES = (".csv", ".parquet", ".pq")

_FORMAT = "vesselid-trial-log"
_FORMAT_VERSION = 1


def _write_csv(data: pd.DataFrame, path: Path, *, append: bool = False) -> None:
    """CSV with every float in its shortest round-trip representation (``repr``).

    Numeric frames go through pyarrow's CSV writer when it is installed (the same
    shortest representation, ~10× faster than pandas); anything else through pandas,
    whose default float formatting is also the shortest round-trip text. With
    ``append`` the rows are added to ``path`` without a header (chunked writing).
    """
    plain_names = not any(set(c) & set(',"\r\n') for c in data.columns)
    if plain_names and all(data[c].dtype.kind in "fi" for c in data.columns):
        try:
            import pyarrow as pa
            import pyarrow.csv as pa_csv
        except ImportError:
            pass
        else:
            table = pa.Table.from_pandas(data, preserve_index=False)
            with open(path, "ab" if append else "wb") as fh:  # header unquoted, as pandas
                if not append:
                    fh.write((",".join(data.columns) + "\n").encode("utf-8"))
                pa_csv.write_csv(table, fh, pa_csv.WriteOptions(include_header=False))
            return
    data.to_csv(path, index=False, mode="a" if append else "w", header=not append)


def _pandas_before(major: int, minor: int) -> bool:
    match = re.match(r"(\d+)\.(\d+)", pd.__version__)
    return match is None or (int(match[1]), int(match[2])) < (major, minor)


# pandas < 3.1 needs the round-trip converter for exact floats; 3.1 deprecates the argument
# because every mode then uses the correctly rounding converter.
_CSV_READ_KWARGS: dict[str, Any] = {"float_precision": "round_trip"} if _pandas_before(3, 1) else {}


class _ParquetUnavailableError(LogValidationError, ImportError):
    """pyarrow is not installed (both a :class:`LogValidationError` and an ImportError)."""


# ----------------------------------------------------------------------------- helpers
def _package_version() -> str:
    try:
        from vesselid import __version__
    except ImportError:  # pragma: no cover - __init__ always defines it
        return "unknown"
    return str(__version__)


def _json_default(obj: Any) -> Any:
    """Convert numpy scalars/arrays, paths and model specs for :func:`json.dumps`."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, ModelSpec):
        return obj.to_dict()
    raise TypeError(f"object of type {type(obj).__name__} is not JSON serialisable")


def _dumps(obj: Any) -> str:
    try:
        return json.dumps(finite_or_none(obj), default=_json_default, indent=2, sort_keys=False,
                          allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise LogValidationError(f"trial log metadata is not JSON-serialisable: {exc}") from exc


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        raise LogValidationError(
            f"unsupported trial log file suffix {path.suffix or '(none)'!r} in {str(path)!r}; "
            f"supported: {', '.join(SUPPORTED_SUFFIXES)}"
        )
    return suffix


def _import_pyarrow() -> tuple[Any, Any]:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError as exc:
        raise _ParquetUnavailableError(
            "reading/writing Parquet trial logs needs pyarrow: pip install 'vesselid[parquet]'"
        ) from exc
    return pa, pq


def _sidecar_path(path: Path) -> Path:
    return path.with_suffix(".json")


def _row_text(data: pd.DataFrame, pos: int) -> str:
    """``"row 17"``, plus the index label when it differs from the position."""
    label = data.index[pos]
    same = isinstance(label, (int, np.integer)) and int(label) == pos
    return f"row {pos}" if same else f"row {pos} (index label {_scalar(label)!r})"


def _experiment_text(data: pd.DataFrame, pos: int) -> str:
    if "experiment" not in data.columns:
        return ""
    return f" in experiment {_scalar(data['experiment'].iloc[pos])!r}"


def _scalar(value: Any) -> Any:
    return value.item() if isinstance(value, np.generic) else value


def _sort_ids(ids: list) -> list:
    try:
        return sorted(ids)
    except TypeError:  # mixed, unorderable ids: keep order of first appearance
        return ids


def _is_real_numeric(series: pd.Series) -> bool:
    dtype = series.dtype
    return (
        pd.api.types.is_numeric_dtype(dtype)
        and not pd.api.types.is_complex_dtype(dtype)
        and not pd.api.types.is_object_dtype(dtype)
    )


# ---------------------------------------------------------------------------- TrialLog
class TrialLog:
    """A trial log: a DataFrame with one row per sample, plus JSON-serialisable metadata.

    Parameters
    ----------
    data : pandas.DataFrame
        The samples. See the module docstring for the column conventions.
    metadata : dict, optional
        JSON-serialisable metadata. Keys used by vesselid: ``"spec"``
        (:meth:`ModelSpec.to_dict`), ``"vesselid_version"``, ``"seed"``, ``"system"``,
        ``"disturbances"``, ``"inputs"``; anything else is kept as is.

    Notes
    -----
    The constructor only stores its arguments; call :meth:`validate` to check the data.
    """

    def __init__(self, data: pd.DataFrame, metadata: dict | None = None) -> None:
        if not isinstance(data, pd.DataFrame):
            raise LogValidationError(
                f"trial log data must be a pandas DataFrame, got {type(data).__name__}"
            )
        self.data: pd.DataFrame = data
        self.metadata: dict = dict(metadata) if metadata is not None else {}

    # ------------------------------------------------------------------ properties
    @property
    def spec(self) -> ModelSpec | None:
        """The model spec stored in ``metadata["spec"]``, or ``None``."""
        raw = self.metadata.get("spec")
        if raw is None:
            return None
        if isinstance(raw, ModelSpec):
            return raw
        return ModelSpec.from_dict(raw)

    @property
    def experiment_ids(self) -> list:
        """Sorted unique values of the ``experiment`` column, or ``[0]`` when it is absent."""
        if "experiment" not in self.data.columns:
            return [0]
        ids = [_scalar(v) for v in pd.unique(self.data["experiment"].dropna())]
        return _sort_ids(ids)

    def experiments(self) -> list[tuple[object, pd.DataFrame]]:
        """Split the log into experiments.

        Returns
        -------
        list of (id, DataFrame)
            One entry per experiment, in :attr:`experiment_ids` order (sorted ids); each
            frame keeps the original row order and index labels. Without an ``experiment``
            column the whole log is experiment ``0``.
        """
        if "experiment" not in self.data.columns:
            return [(0, self.data)]
        col = self.data["experiment"]
        out = []
        for eid in self.experiment_ids:
            out.append((eid, self.data.loc[(col == eid).to_numpy()]))
        return out

    def to_frame(self) -> pd.DataFrame:
        """The data as a DataFrame (not a copy)."""
        return self.data

    def __len__(self) -> int:
        return len(self.data)

    def __repr__(self) -> str:
        cols = [str(c) for c in self.data.columns]
        shown = cols if len(cols) <= 8 else [*cols[:7], "...", cols[-1]]
        n_exp = len(self.experiment_ids)
        return (
            f"TrialLog({len(self.data)} rows, {n_exp} experiment{'s' if n_exp != 1 else ''}, "
            f"columns=[{', '.join(shown)}])"
        )

    # ------------------------------------------------------------------ validation
    def validate(
        self,
        spec: ModelSpec | None = None,
        *,
        columns: Sequence[str] | None = None,
        min_samples: int = 2,
    ) -> TrialLog:
        """Check the log against a model spec.

        Parameters
        ----------
        spec : ModelSpec, optional
            Model whose states, inputs and aggregate sensor columns must be present.
            Defaults to :attr:`spec` (the spec in the metadata), if any.
        columns : sequence of str, optional
            Further required columns.
        min_samples : int, default 2
            Minimum number of rows per experiment.

        Returns
        -------
        TrialLog
            ``self``, so that calls can be chained.

        Raises
        ------
        LogValidationError
            Missing columns (all of them are listed), a non-numeric required column,
            NaN/±inf in a required column or in ``time`` (naming the column and first row),
            ``time`` not strictly increasing within an experiment, or an experiment with
            fewer than ``min_samples`` rows.
        """
        self._validate(spec, columns=columns, min_samples=min_samples)
        return self

    def _validate(
        self,
        spec: ModelSpec | None = None,
        *,
        columns: Sequence[str] | None = None,
        min_samples: int = 2,
    ) -> list[tuple[object, np.ndarray]]:
        """:meth:`validate`, returning the row positions of every experiment it split the
        log into (``_positions_by_experiment``), so that a caller reading the experiments
        (``identify``'s ``from_log``) does not split the log again."""
        if spec is None:
            spec = self.spec
        data = self.data
        required: list[str] = []
        if spec is not None:  # derived signals: the measured columns they are built from
            required.extend(spec.measured_columns)
        if columns is not None:
            if isinstance(columns, str):
                columns = [columns]
            required.extend(columns)
        required = list(dict.fromkeys(required))

        available = list(data.columns)
        missing = [c for c in required if c not in data.columns]
        if missing:
            what = "column" if len(missing) == 1 else "columns"
            raise LogValidationError(
                f"trial log is missing {what} {missing}; available columns: {available}"
            )
        duplicated = ([] if data.columns.is_unique else  # cached on the index: no scan
                      sorted({str(c) for c in data.columns[data.columns.duplicated()]}))
        if duplicated:
            raise LogValidationError(f"trial log has duplicated columns {duplicated}")

        checked = [*required, "time"] if "time" in data.columns else required
        checked = list(dict.fromkeys(checked))
        series = {col: data[col] for col in checked}  # each column looked up once
        for col in checked:
            if not _is_real_numeric(series[col]):
                raise LogValidationError(
                    f"column {col!r} must be numeric, got dtype {series[col].dtype}"
                )

        if "experiment" in data.columns:
            exp = data["experiment"]
            # integer ids cannot be missing: no isna pass
            bad = (np.zeros(0, dtype=bool) if isinstance(exp.dtype, np.dtype)
                   and exp.dtype.kind in "iu" else exp.isna().to_numpy())
            if bad.any():
                pos = int(np.flatnonzero(bad)[0])
                raise LogValidationError(
                    f"column 'experiment' has a missing value at {_row_text(data, pos)}"
                )

        if min_samples < 1:
            raise LogValidationError(f"min_samples must be at least 1, got {min_samples}")
        offsets = _positions_by_experiment(data)  # the split of experiments(), no copies
        sizes = [(eid, pos.size) for eid, pos in offsets] or [(0, len(data))]  # empty frame
        for eid, size in sizes:
            if size < min_samples:
                raise LogValidationError(
                    f"experiment {eid!r} has {size} sample{'s' if size != 1 else ''}; "
                    f"at least {min_samples} are required"
                )

        for col in checked:
            values = series[col].to_numpy(dtype=float, na_value=np.nan)
            bad = ~np.isfinite(values)
            if bad.any():
                positions = np.flatnonzero(bad)
                pos = int(positions[0])
                value = values[pos]
                kind = "NaN" if math.isnan(value) else ("inf" if value > 0 else "-inf")
                more = (
                    f" ({positions.size} non-finite values in total)" if positions.size > 1 else ""
                )
                raise LogValidationError(
                    f"column {col!r} has {kind} at {_row_text(data, pos)}"
                    f"{_experiment_text(data, pos)}{more}"
                )

        if "time" in data.columns:
            times = series["time"].to_numpy(dtype=float)
            for eid, pos in offsets:
                if pos.size < 2:
                    continue
                t = times[pos]
                steps = np.diff(t)
                bad = np.flatnonzero(~(steps > 0))
                if bad.size:
                    k = int(bad[0]) + 1
                    row = int(pos[k])
                    raise LogValidationError(
                        f"column 'time' is not strictly increasing in experiment {eid!r} at "
                        f"{_row_text(data, row)}: {float(t[k])!r} follows {float(t[k - 1])!r}"
                    )
        return offsets

    # ------------------------------------------------------------------------ I/O
    def save(self, path: str | Path, *, extra: dict[str | Path, str] | None = None) -> Path:
        """Write the log atomically.

        Parameters
        ----------
        path : str or Path
            ``.csv``: CSV (no index, floats in their shortest round-trip text) plus a JSON sidecar
            ``path.with_suffix(".json")`` with the metadata and column dtypes.
            ``.parquet`` / ``.pq``: Parquet (with page checksums) holding the metadata in
            the schema metadata under ``b"vesselid"`` (needs pyarrow:
            ``pip install 'vesselid[parquet]'``).
        extra : dict path -> str, optional
            Further text files (e.g. the model spec TOML) placed together with the log:
            all files appear, or none does.

        Returns
        -------
        Path
            The path of the data file.

        Raises
        ------
        LogValidationError
            Unsupported suffix, non-string or duplicated column names, metadata that is
            not JSON-serialisable, or pyarrow missing for Parquet.
        OSError
            The output cannot be written (the message names the path).

        Notes
        -----
        Every file is written to a temporary file beside its target and renamed into
        place only once all files are complete; if writing fails nothing is left behind
        and existing files are untouched. The row index is not saved.
        """
        with TrialLogWriter(path, self.metadata, extra=extra) as writer:
            writer.append(self.data)
        return Path(path)

    @classmethod
    def load(
        cls, path: str | Path, spec: ModelSpec | None = None, validate: bool = True,
        *, truth: bool = True,
    ) -> TrialLog:
        """Read a log written by :meth:`save`, or a user's own CSV/Parquet file.

        Parameters
        ----------
        path : str or Path
            A ``.csv`` file (with an optional JSON sidecar ``path.with_suffix(".json")``)
            or a ``.parquet`` / ``.pq`` file.
        spec : ModelSpec, optional
            Model to validate against; defaults to the spec stored in the metadata.
        validate : bool, default True
            Run :meth:`validate` after reading.
        truth : bool, default True
            Read the simulator's ground-truth columns (names starting with
            :data:`TRUTH_PREFIX`). ``False`` leaves those the model spec (``spec``, else
            the file's) does not name in the file: what identification needs (no
            estimator reads them; on a long simulated log they are a large share of the
            table).

        Raises
        ------
        LogValidationError
            Missing or unreadable file, unsupported suffix, invalid sidecar, or a log
            that fails validation.
        """
        path = Path(path)
        suffix = _suffix(path)
        if not path.is_file():
            raise LogValidationError(f"trial log file {str(path)!r} does not exist")
        keep = None if truth else functools.partial(_truth_filter, spec)
        if suffix == ".csv":
            data, envelope = _read_csv(path, keep)
        else:
            data, envelope = _read_parquet(path, keep)
        metadata = envelope.get("metadata", {}) if envelope else {}
        if not isinstance(metadata, dict):
            raise LogValidationError(f"{path}: trial log metadata must be a JSON object")
        log = cls(data, metadata)
        if validate:
            try:
                log.validate(spec if spec is not None else log.spec)
            except LogValidationError as exc:
                raise LogValidationError(f"{path}: {exc}") from exc
        return log


class TrialLogWriter:
    """Write a trial log chunk by chunk, atomically, without holding it in memory.

    ``with TrialLogWriter(path, metadata) as w: w.append(frame); ...`` appends the rows
    of every frame in order (same columns and dtypes each time) to a temporary file;
    when the block completes the data file, its sidecar (CSV) and any ``extra`` files
    appear together, and on any error none of them does. One ``append`` writes exactly
    the bytes :meth:`TrialLog.save` writes for that frame.

    Parameters
    ----------
    path : str or Path
        ``.csv`` (plus sidecar ``.json``) or ``.parquet`` / ``.pq``.
    metadata : dict, optional
        JSON-serialisable metadata; may be updated until the first ``append``.
    extra : dict path -> str, optional
        Text files written together with the log (e.g. the model spec).
    """

    def __init__(self, path: str | Path, metadata: dict | None = None, *,
                 extra: dict[str | Path, str] | None = None) -> None:
        self.path = Path(path)
        self._suffix = _suffix(self.path)
        self.metadata: dict = dict(metadata) if metadata is not None else {}
        self.extra = {Path(k): v for k, v in (extra or {}).items()}
        self.rows = 0
        self._columns: list[str] | None = None
        self._dtypes: dict[str, str] | None = None
        self._text: str | None = None
        self._group: Any = None
        self._tmps: list[Path] = []
        self._pq_writer: Any = None
        self._schema: Any = None

    def _targets(self) -> list[Path]:
        targets = [self.path]
        if self._suffix == ".csv":
            targets.append(_sidecar_path(self.path))
        return targets + list(self.extra)

    def __enter__(self) -> TrialLogWriter:
        _dumps(self.metadata)  # fail on unserialisable metadata before touching the disk
        if self._suffix != ".csv":
            _import_pyarrow()
        self._group = atomic_group(self._targets())
        self._tmps = self._group.__enter__()
        return self

    def _envelope(self, data: pd.DataFrame) -> str:
        bad_names = [c for c in data.columns if not isinstance(c, str)]
        if bad_names:
            raise LogValidationError(f"trial log column names must be strings, got {bad_names}")
        duplicated = sorted(set(data.columns[data.columns.duplicated()]))
        if duplicated:
            raise LogValidationError(f"trial log has duplicated columns {duplicated}")
        envelope = {
            "format": _FORMAT,
            "format_version": _FORMAT_VERSION,
            "vesselid_version": _package_version(),
            "columns": list(data.columns),
            "dtypes": {c: str(data[c].dtype) for c in data.columns},
            "metadata": self.metadata,
        }
        return _dumps(envelope)

    def append(self, data: pd.DataFrame) -> None:
        """Append the rows of ``data`` (same columns and dtypes as the first chunk)."""
        if self._group is None:
            raise RuntimeError("TrialLogWriter.append outside its 'with' block")
        if self._columns is None:
            self._text = self._envelope(data)
            self._columns = list(data.columns)
            self._dtypes = {c: str(data[c].dtype) for c in data.columns}
        elif (list(data.columns) != self._columns
              or {c: str(data[c].dtype) for c in data.columns} != self._dtypes):
            raise LogValidationError(
                f"chunk columns/dtypes {list(data.columns)} differ from the first chunk's "
                f"{self._columns}")
        tmp = self._tmps[0]
        if self._suffix == ".csv":
            first = self.rows == 0
            _write_csv(data, tmp, append=not first)
        else:
            pa, pq = _import_pyarrow()
            table = pa.Table.from_pandas(data, preserve_index=False)
            if self._pq_writer is None:
                schema_meta = dict(table.schema.metadata or {})
                schema_meta[PARQUET_METADATA_KEY] = self._text.encode("utf-8")
                self._schema = table.schema.with_metadata(schema_meta)
                self._pq_writer = pq.ParquetWriter(tmp, self._schema, write_page_checksum=True)
            self._pq_writer.write_table(table.replace_schema_metadata(self._schema.metadata))
        self.rows += len(data)

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        group, self._group = self._group, None
        try:
            if exc_type is None:
                if self._columns is None:
                    self.append(pd.DataFrame())
                if self._pq_writer is not None:
                    self._pq_writer.close()
                if self._suffix == ".csv":
                    self._tmps[1].write_text(self._text + "\n", encoding="utf-8")
                offset = 2 if self._suffix == ".csv" else 1
                for tmp, text in zip(self._tmps[offset:], self.extra.values(), strict=True):
                    tmp.write_text(text, encoding="utf-8")
            elif self._pq_writer is not None:
                with contextlib.suppress(Exception):
                    self._pq_writer.close()
        except BaseException as err:
            group.__exit__(type(err), err, err.__traceback__)
            raise
        group.__exit__(exc_type, exc, tb)


def estimate_shape(path: str | Path) -> tuple[int, int]:
    """Rows and columns of a log file without reading it (for :mod:`vesselid.core.limits`).

    Parquet: exact, from the footer. CSV: the header's columns and the file size
    divided by the mean length of the first data lines.

    Raises
    ------
    LogValidationError
        Unsupported suffix, missing file or unreadable footer.
    OSError
        The file cannot be opened.
    """
    path = Path(path)
    suffix = _suffix(path)
    if path.is_dir():
        raise IsADirectoryError(21, "trial log path is a directory", str(path))
    if not path.is_file():
        raise LogValidationError(f"trial log file {str(path)!r} does not exist")
    if suffix != ".csv":
        pa, pq = _import_pyarrow()
        try:
            meta = pq.read_metadata(path)
        except (pa.ArrowException, OSError, ValueError) as exc:
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise LogValidationError(f"{path}: cannot read Parquet (corrupt or not Parquet): "
                                     f"{msg}") from exc
        return int(meta.num_rows), int(meta.num_columns)
    size = path.stat().st_size
    with open(path, "rb") as fh:
        block = fh.read(1 << 16)  # never more: a file may be one endless line
    lines = block.split(b"\n")
    header = lines[0]
    cols = header.count(b",") + 1
    sample = lines[1:-1]  # complete data lines
    if not sample:  # no complete line in the first 64 kB: count bytes as values
        return (max(0, size - len(header)) // 8 if size > len(block) else 0), cols
    per_line = max(1.0, sum(len(line) + 1 for line in sample) / len(sample))
    return int((size - len(header) - 1) / per_line) + 1, cols


def _positions_by_experiment(data: pd.DataFrame) -> list[tuple[object, np.ndarray]]:
    """0-based row positions of every experiment, in sorted-id order."""
    if "experiment" not in data.columns:
        return [(0, np.arange(len(data)))]
    col = data["experiment"]
    if isinstance(col.dtype, np.dtype) and col.dtype.kind in "iu":
        # integer ids (no missing value possible): the same split on the numpy values,
        # without the Series copies and comparisons
        vals = col.to_numpy()
        ids = _sort_ids([_scalar(v) for v in pd.unique(vals)])
        return [(eid, np.flatnonzero(vals == eid)) for eid in ids]
    ids = _sort_ids([_scalar(v) for v in pd.unique(col.dropna())])
    return [(eid, np.flatnonzero((col == eid).to_numpy())) for eid in ids]


#: Types of the metadata entries vesselid writes (others are kept as they are).
_METADATA_TYPES: dict[str, tuple[tuple[type, ...], str]] = {
    "spec": ((dict,), "a JSON object (model spec)"),
    "vesselid_version": ((str,), "a string"),
    "command": ((str,), "a string"),
    "seed": ((int, type(None)), "an integer or null"),
    "seeds": ((list,), "a list of integers or nulls"),
    "spawn_keys": ((list,), "a list of lists of integers"),
    "experiments": ((int,), "an integer"),
    "samples_per_experiment": ((int,), "an integer"),
}


def _type_name(value: Any) -> str:
    return {dict: "object", list: "list", str: "string", bool: "boolean", int: "integer",
            float: "number", type(None): "null"}.get(type(value), type(value).__name__)


def _check_metadata(metadata: Any, where: str) -> dict:
    """Check the type of every metadata entry vesselid relies on."""
    if not isinstance(metadata, dict):
        raise LogValidationError(
            f"{where}: trial log metadata must be a JSON object, got {_type_name(metadata)}")
    for key, (types, text) in _METADATA_TYPES.items():
        if key not in metadata:
            continue
        value = metadata[key]
        ok = isinstance(value, types) and not isinstance(value, bool)
        if ok and key == "seeds":
            ok = all(v is None or (isinstance(v, int) and not isinstance(v, bool)) for v in value)
        if ok and key == "spawn_keys":
            ok = all(isinstance(k, list) and all(isinstance(i, int) and not isinstance(i, bool)
                                                 for i in k) for k in value)
        if ok and key in ("experiments", "samples_per_experiment"):
            ok = value >= 0
        if not ok:
            raise LogValidationError(
                f"{where}: metadata entry {key!r} must be {text}, got {_type_name(value)} "
                f"{value!r:.60}")
    if "spec" in metadata:
        try:
            ModelSpec.from_dict(metadata["spec"])
        except ModelSpecError as exc:
            raise LogValidationError(f"{where}: metadata entry 'spec': {exc}") from exc
    return metadata


def _read_envelope(text: str | bytes, where: str) -> dict:
    if isinstance(text, bytes):
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise LogValidationError(
                f"{where}: trial log metadata is not UTF-8 text: {exc}") from exc
    try:
        envelope = json.loads(text, parse_constant=_reject_constant)
    except ValueError as exc:
        raise LogValidationError(f"{where}: invalid trial log metadata JSON: {exc}") from exc
    if not isinstance(envelope, dict):
        raise LogValidationError(
            f"{where}: trial log metadata must be a JSON object, got {_type_name(envelope)}")
    if envelope.get("format") != _FORMAT:
        # A plain JSON object written by hand: treat it as the metadata itself.
        envelope = {"metadata": envelope}
    else:
        version = envelope.get("format_version", _FORMAT_VERSION)
        if not isinstance(version, int) or isinstance(version, bool):
            raise LogValidationError(
                f"{where}: 'format_version' must be an integer, got {_type_name(version)}")
        if version > _FORMAT_VERSION:
            raise LogValidationError(
                f"{where}: trial log format version {version} is newer than this vesselid "
                f"understands ({_FORMAT_VERSION}); upgrade vesselid")
        columns = envelope.get("columns")
        if columns is not None and not (
                isinstance(columns, list) and all(isinstance(c, str) for c in columns)):
            raise LogValidationError(f"{where}: 'columns' must be a list of strings")
        if columns is not None and len(set(columns)) != len(columns):
            dup = sorted({c for c in columns if columns.count(c) > 1})
            raise LogValidationError(f"{where}: 'columns' lists duplicated names {dup}")
        dtypes = envelope.get("dtypes", {})
        if not isinstance(dtypes, dict):
            raise LogValidationError(
                f"{where}: 'dtypes' must be a JSON object, got {_type_name(dtypes)}")
        for col, name in dtypes.items():
            if not isinstance(name, str):
                raise LogValidationError(
                    f"{where}: dtype of column {col!r} must be a string, got "
                    f"{_type_name(name)} {name!r:.40}")
            try:
                pd.api.types.pandas_dtype(name)
            except (TypeError, ValueError) as exc:
                raise LogValidationError(
                    f"{where}: dtype {name!r} of column {col!r} is not a dtype") from exc
    envelope["metadata"] = _check_metadata(envelope.get("metadata", {}), where)
    return envelope


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not valid JSON")


def _csv_header(path: Path) -> list[str]:
    """The header row as written (pandas renames duplicated names to ``w.1``)."""
    try:
        with open(path, encoding="utf-8", newline="") as fh:
            return next(csv.reader(fh), [])
    except UnicodeDecodeError as exc:
        raise LogValidationError(f"{path}: cannot read CSV: not UTF-8 text ({exc})") from exc
    except csv.Error as exc:
        raise LogValidationError(f"{path}: cannot read CSV header: {exc}") from exc


#: Name prefix of the simulator's ground-truth columns (``true_w``, ``true_current_w``,
#: ...), which :meth:`TrialLog.load` can leave unread (``truth=False``).
TRUTH_PREFIX = "true_"


def _truth_filter(spec: ModelSpec | None, envelope: dict) -> Any:
    """The columns :meth:`TrialLog.load` reads with ``truth=False``: all but the
    ground-truth columns (:data:`TRUTH_PREFIX`) that the spec (``spec``, else the one in
    the file's metadata ``envelope``) does not mention."""
    raw = spec.to_dict() if spec is not None else (envelope.get("metadata") or {}).get("spec")
    named = json.dumps(raw, default=str) if raw is not None else ""

    def keep(name: object) -> bool:
        return not str(name).startswith(TRUTH_PREFIX) or str(name) in named

    return keep


def _read_csv(path: Path, keep: Any = None) -> tuple[pd.DataFrame, dict]:
    sidecar = _sidecar_path(path)
    envelope: dict = {}
    dtypes: dict[str, str] = {}
    if sidecar.is_file():
        envelope = _read_envelope(sidecar.read_bytes(), str(sidecar))
        dtypes = envelope.get("dtypes") or {}
    raw_header = _csv_header(path)
    seen: set[str] = set()
    duplicated = sorted({c for c in raw_header if c in seen or seen.add(c)})
    if duplicated:
        raise LogValidationError(f"{path}: CSV header has duplicated column names {duplicated}")
    try:
        header = pd.read_csv(path, nrows=0)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise LogValidationError(f"{path}: cannot read CSV: {exc}") from exc
    if dtypes and list(header.columns) != list(envelope.get("columns") or dtypes):
        warnings.warn(
            f"{sidecar} describes columns {list(envelope.get('columns') or dtypes)} but "
            f"{path} has {list(header.columns)}; ignoring the recorded dtypes",
            UserWarning,
            stacklevel=3,
        )
        dtypes = {}
    # Columns whose dtype read_csv can take directly; the rest are cast afterwards.
    direct: dict[str, Any] = {}
    later: dict[str, str] = {}
    for col, name in dtypes.items():
        if name.startswith(("datetime64", "timedelta64", "period", "interval")):
            later[col] = name
        else:
            direct[col] = name
    if keep is not None:  # the columns asked for (dtypes of the others do not apply)
        keep = keep(envelope)
        direct = {c: t for c, t in direct.items() if keep(c)}
        later = {c: t for c, t in later.items() if keep(c)}
    try:
        # every column is parsed (``usecols`` would let ragged rows pass unnoticed); the
        # unasked ones are dropped at once
        data = pd.read_csv(path, dtype=direct or None, **_CSV_READ_KWARGS)
        if keep is not None:
            data = data.drop(columns=[c for c in data.columns if not keep(c)])
        for col, name in later.items():
            data[col] = data[col].astype(name)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise LogValidationError(f"{path}: cannot read CSV: {exc}") from exc
    except (TypeError, ValueError, OverflowError) as exc:
        raise LogValidationError(
            f"{path}: values do not match the dtypes recorded in {sidecar.name}: {exc}"
        ) from exc
    return data, envelope


def _read_parquet(path: Path, keep: Any = None) -> tuple[pd.DataFrame, dict]:
    pa, pq = _import_pyarrow()
    try:
        schema = pq.read_schema(path)
        names = list(schema.names)
        seen: set[str] = set()
        duplicated = sorted({c for c in names if c in seen or seen.add(c)})
        if duplicated:
            raise LogValidationError(f"{path}: Parquet file has duplicated column names "
                                     f"{duplicated}")
        if keep is not None:  # the columns asked for, from the footer's metadata
            raw = (schema.metadata or {}).get(PARQUET_METADATA_KEY)
            keep = keep(_read_envelope(raw, str(path)) if raw is not None else {})
        # one file, read as it is (no dataset layer: its modules stay unloaded)
        table = pq.ParquetFile(path, page_checksum_verification=True).read(
            columns=None if keep is None else [c for c in names if keep(c)])
        raw = (table.schema.metadata or {}).get(PARQUET_METADATA_KEY)
        envelope = _read_envelope(raw, str(path)) if raw is not None else {}
        # one block per column, each Arrow buffer freed as soon as it is converted, and
        # the pool's freed pages handed back: the frame is the only copy that stays
        data = table.to_pandas(split_blocks=True, self_destruct=True)
        del table
        pa.default_memory_pool().release_unused()
    except LogValidationError:
        raise
    except (pa.ArrowException, OSError, ValueError, TypeError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise LogValidationError(f"{path}: cannot read Parquet (corrupt or not Parquet): "
                                 f"{msg}") from exc
    return data, envelope


# ------------------------------------------------------------------------- concat_logs
def concat_logs(logs: Sequence[TrialLog]) -> TrialLog:
    """Stack logs as separate experiments.

    Parameters
    ----------
    logs : sequence of TrialLog
        Logs with the same set of columns. Each experiment of each log becomes its own
        experiment; ids are renumbered ``0, 1, ...`` in order (log by log, and within a
        log in :attr:`TrialLog.experiment_ids` order).

    Returns
    -------
    TrialLog
        An integer ``experiment`` column (first column unless the first log already has
        one), a fresh ``RangeIndex``, and a copy of the first log's metadata. When any log
        has a ``"seed"``, ``metadata["seeds"]`` lists every log's seed in order (``None``
        where absent), so the others' seeds are kept.

    Raises
    ------
    LogValidationError
        No logs, or logs with different columns.
    """
    logs = list(logs)
    if not logs:
        raise LogValidationError("concat_logs needs at least one trial log")
    first = logs[0]
    reference = [c for c in first.data.columns if c != "experiment"]
    frames = []
    next_id = 0
    for i, log in enumerate(logs):
        cols = [c for c in log.data.columns if c != "experiment"]
        if set(cols) != set(reference):
            extra = sorted(set(cols) - set(reference))
            lacking = sorted(set(reference) - set(cols))
            raise LogValidationError(
                f"trial log {i} has different columns from log 0: extra {extra}, missing {lacking}"
            )
        for _, frame in log.experiments():
            part = frame[reference].copy()
            part.insert(0, "experiment", np.full(len(part), next_id, dtype=np.int64))
            frames.append(part)
            next_id += 1
    data = pd.concat(frames, ignore_index=True)
    if "experiment" in first.data.columns:
        data = data[list(first.data.columns)]
    metadata = dict(first.metadata)
    seeds = [log.metadata.get("seed") for log in logs]
    if any(s is not None for s in seeds):
        metadata["seeds"] = seeds
    return TrialLog(data, metadata)
