"""Record environment episodes as trial logs (docs/architecture.md "Trial log").

:class:`TrialRecorder` wraps a single environment, :class:`VectorTrialRecorder` a
vector environment. Every episode becomes one ``experiment`` of a
:class:`~vesselid.data.logs.TrialLog`, so ``vesselid identify LOG --model SPEC.toml`` runs
directly on environment data::

    env = TrialRecorder(gym.make("vesselid/Heave-v0"))
    obs, info = env.reset(seed=0)
    for _ in range(1000):
        obs, reward, terminated, truncated, info = env.step(policy(obs))
        if terminated or truncated:
            obs, info = env.reset()
    env.save("heave.csv")  # + heave.json sidecar with the metadata

Environment contract
--------------------
The recorder reads everything through ``env.unwrapped`` (attribute names exact):

``model_spec`` : :class:`vesselid.model.spec.ModelSpec`
    The identification structure of the recorded data. ``model_spec.states`` and
    ``model_spec.inputs`` name the measured state and input columns, ``model_spec.sensors``
    the disturbance-sensor columns of its aggregate relations.
``dt`` : float (optional)
    Sample time; the ``time`` column is ``k · dt``. Default ``model_spec.dt``, else 1.0.
``log_row(info) -> dict[str, float]``
    The log columns *at the time of the observation* that came with ``info`` (from
    ``reset`` or ``step``): every ``model_spec.states`` name (the state *measurement*),
    every ``model_spec.sensors`` name, plus any extra columns (ground truth named
    ``true_<name>``, references, ...). Values are Python/numpy floats. The same keys in
    the same order on every call for one environment instance; never ``experiment``,
    ``time`` or an input name.
``log_inputs(action) -> dict[str, float]``
    The physical inputs the environment applies for ``action`` (after clipping and
    scaling): exactly the ``model_spec.inputs`` names. Must not change the environment.
``log_metadata() -> dict`` (optional)
    JSON-serialisable settings (disturbances, sensors, ...), stored as
    ``metadata["env_settings"]``.

A vector environment (on ``vector_env.unwrapped``) provides the same names, with
``log_row(infos)`` and ``log_inputs(actions)`` returning arrays of shape ``(num_envs,)``
per column, and ``metadata["autoreset_mode"]`` equal to
``gymnasium.vector.AutoresetMode.NEXT_STEP`` or ``SAME_STEP``.

Row alignment
-------------
Row ``k`` of an experiment holds the measurements ``y(k)`` (from the observation's
``info``) and the input ``u(k)`` applied *at* time ``k``, so consecutive rows satisfy the
model ``x(k+1) = f(x(k) + v(k), u(k)) + w(k)``:

* ``reset`` opens row 0 with ``log_row(info)``;
* ``step(action)`` completes the open row with ``log_inputs(action)`` and opens the next
  row with the new ``log_row(info)``;
* the final open row of an episode (its last observation, which no input follows) is
  **dropped**: an episode of ``T`` steps gives ``T`` rows ``y(0..T-1), u(0..T-1)``. No
  input is invented, and on noise-free data every pair of consecutive rows satisfies the
  model exactly.

With the single recorder an episode runs from one ``reset`` to the next (stepping on
after ``terminated``/``truncated`` keeps extending it). With a vector recorder an
episode of a sub-environment ends where the vector environment autoresets it.
Episodes still running when :meth:`~TrialRecorder.to_log` is called are included
(their completed rows) unless ``include_unfinished=False``.

Closed-loop logs
----------------
A controller in the loop makes the input depend on the noise; closed-loop estimators
(``vesselid identify --method cl-iv``) need the external signals and the controller.
:meth:`TrialRecorder.annotate` records external signals of the row about to be completed
(call it before ``step``: e.g. the dither added to the controller's output) as extra
columns, and :meth:`TrialRecorder.declare_closed_loop` names the controller and the
reference/dither columns in ``metadata["closed_loop"]``
(:func:`vesselid.plant.closedloop.closed_loop_metadata`)::

    rec = TrialRecorder(gym.make("vesselid/Heave-v0"))
    rec.declare_closed_loop(pid, reference={"w": "w_ref"}, dither={"tau": "tau_dither"})
    obs, info = rec.reset(seed=0)
    for k in range(n):
        d = dither[k]
        tau = policy([info["y1"]], [info["w_ref"]], [d])[0]
        rec.annotate(tau_dither=d)
        obs, _, term, trunc, info = rec.step(action_of(tau))

Wrappers between the recorder and the base environment must not change actions or
``info`` (``TimeLimit``, ``OrderEnforcing`` and ``PassiveEnvChecker`` do not); put
action-rescaling wrappers outside the recorder.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd
from gymnasium.vector import AutoresetMode

from vesselid.data.logs import TrialLog
from vesselid.errors import VesselidError
from vesselid.model.spec import ModelSpec

__all__ = ["TrialRecorder", "VectorTrialRecorder"]


# --------------------------------------------------------------------------- helpers
def _contract(base: Any) -> ModelSpec:
    missing = [name for name in ("model_spec", "log_row", "log_inputs") if not hasattr(base, name)]
    if missing:
        raise VesselidError(
            f"{type(base).__name__} does not implement the recorder contract: missing "
            f"{missing} (see vesselid.envs.recorder)"
        )
    spec = base.model_spec
    if not isinstance(spec, ModelSpec):
        raise VesselidError(
            f"{type(base).__name__}.model_spec must be a ModelSpec, got {type(spec).__name__}"
        )
    return spec


def _jsonable(value: Any) -> Any:
    """A JSON-serialisable copy of ``value`` (unknown objects become their repr)."""
    try:
        return json.loads(json.dumps(value, default=_json_default))
    except (TypeError, ValueError):
        return repr(value)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (tuple, set, frozenset)):
        return list(obj)
    if isinstance(obj, ModelSpec):
        return obj.to_dict()
    return repr(obj)


def _check_columns(spec: ModelSpec, columns: Sequence[str], inputs: Sequence[str]) -> None:
    reserved = {"experiment", "time", *spec.inputs}
    clash = [c for c in columns if c in reserved]
    if clash:
        raise VesselidError(f"log_row returned reserved column names {clash}")
    missing = [c for c in (*spec.states, *spec.sensors) if c not in columns]
    if missing:
        raise VesselidError(f"log_row does not return the spec's columns {missing}")
    if list(inputs) != list(spec.inputs):
        raise VesselidError(
            f"log_inputs returned {list(inputs)}, expected the spec's inputs {list(spec.inputs)}"
        )


def _column_order(spec: ModelSpec, measured: Sequence[str]) -> list[str]:
    """``states, inputs, sensors, everything else`` (in ``log_row`` order)."""
    first = [*spec.states, *spec.inputs, *spec.sensors]
    return first + [c for c in measured if c not in first]


def _metadata(
    env: Any, base: Any, spec: ModelSpec, seeds: list, episodes: list[dict]
) -> dict[str, Any]:
    from vesselid import __version__

    env_spec = getattr(env, "spec", None) or getattr(base, "spec", None)
    meta: dict[str, Any] = {
        "spec": spec.to_dict(),
        "vesselid_version": __version__,
        "seed": seeds[0] if seeds else None,
        "reset_seeds": list(seeds),
        "env_id": getattr(env_spec, "id", None),
        "env_kwargs": _jsonable(dict(getattr(env_spec, "kwargs", {}) or {})),
        "env_class": f"{type(base).__module__}.{type(base).__qualname__}",
        "recorder": {
            "alignment": "row k: measurements y(k) and the input u(k) applied at k; "
            "the last observation of an episode (no input follows) is dropped",
        },
        "episodes": episodes,
    }
    settings = getattr(base, "log_metadata", None)
    if callable(settings):
        meta["env_settings"] = _jsonable(settings())
    return meta


def _sample_time(base: Any, spec: ModelSpec) -> float:
    dt = getattr(base, "dt", None) or spec.dt or 1.0
    dt = float(dt)
    if not (np.isfinite(dt) and dt > 0):
        raise VesselidError(f"sample time dt must be positive, got {dt}")
    return dt


def _frame(
    spec: ModelSpec,
    dt: float,
    measured: Sequence[str],
    inputs: Sequence[str],
    experiment: np.ndarray,
    k: np.ndarray,
    meas: np.ndarray,
    inp: np.ndarray,
) -> pd.DataFrame:
    cols: dict[str, np.ndarray] = {
        "experiment": np.asarray(experiment, dtype=np.int64),
        "time": np.asarray(k, dtype=np.float64) * dt,
    }
    values = {name: meas[:, j] for j, name in enumerate(measured)}
    values.update({name: inp[:, j] for j, name in enumerate(inputs)})
    for name in _column_order(spec, measured):
        cols[name] = np.asarray(values[name], dtype=np.float64)
    return pd.DataFrame(cols)


# ---------------------------------------------------------------------- single env
class TrialRecorder(gym.Wrapper):
    """Record the episodes of a single environment as a trial log.

    Parameters
    ----------
    env : gymnasium.Env
        An environment whose ``unwrapped`` implements the recorder contract (module
        docstring), e.g. ``gym.make("vesselid/Heave-v0")``.

    Notes
    -----
    Recording costs a few microseconds per step (two dict look-ups and list appends);
    call :meth:`clear` to drop what was recorded.
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self._spec = _contract(env.unwrapped)
        self._measured: tuple[str, ...] | None = None
        self._inputs: tuple[str, ...] | None = None
        self._closed_loop: dict[str, Any] | None = None
        self.clear()

    # ------------------------------------------------------------------ state
    def clear(self) -> None:
        """Forget every recorded episode (the open episode continues)."""
        self._episodes: list[dict[str, Any]] = []
        self._meas: list[tuple[float, ...]] = []
        self._inp: list[tuple[float, ...]] = []
        self._seeds: list = []
        self._ep_meta: dict[str, Any] = {}
        self._open = False
        self._ann: list[dict[str, float]] = []
        self._pending: dict[str, float] = {}

    @property
    def model_spec(self) -> ModelSpec:
        """Identification structure of the recorded data."""
        return self._spec

    @property
    def num_episodes(self) -> int:
        """Episodes recorded so far, including the running one."""
        return len(self._episodes) + (1 if self._open else 0)

    def _row(self, info: dict[str, Any]) -> tuple[float, ...]:
        row = self.env.unwrapped.log_row(info)
        keys = tuple(row)
        self._measured = _same_columns(keys, self._measured)
        return tuple(row.values())

    def _close_episode(self) -> None:
        if self._open:
            self._ep_meta["steps"] = len(self._inp)
            self._episodes.append(
                {"meas": self._meas[: len(self._inp)], "inp": self._inp, "ann": self._ann,
                 **self._ep_meta}
            )
        self._meas, self._inp, self._ann, self._open = [], [], [], False

    # ---------------------------------------------------------- closed loop
    def annotate(self, **values: float) -> None:
        """External signals (reference, dither, ...) of the row the next :meth:`step`
        completes, logged as extra columns (rows without a value get NaN)."""
        reserved = {"experiment", "time", *self._spec.inputs, *self._spec.states,
                    *self._spec.sensors}
        clash = sorted(set(values) & reserved)
        if clash:
            raise VesselidError(f"annotate: reserved column names {clash}")
        self._pending = {k: float(v) for k, v in values.items()}

    def declare_closed_loop(self, controller: Any = None, *,
                            reference: dict[str, str] | None = None,
                            dither: dict[str, str] | None = None) -> None:
        """Record that the episodes run in closed loop: ``metadata["closed_loop"]`` names
        the controller (a :class:`vesselid.plant.closedloop.PID`, a JSON description, or None
        when it cannot be described) and the log columns of the reference (state ->
        column) and of the dither (input -> column)."""
        from vesselid.plant.closedloop import closed_loop_metadata

        self._closed_loop = closed_loop_metadata(controller, reference or {}, dither or {})

    # -------------------------------------------------------------------- API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        self._close_episode()
        self._seeds.append(seed)
        self._ep_meta = {"seed": seed, "terminated": False, "truncated": False}
        self._meas = [self._row(info)]
        self._inp = []
        self._open = True
        return obs, info

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        if not self._open:
            raise VesselidError("call reset() before step() on a TrialRecorder")
        inputs = self.env.unwrapped.log_inputs(action)
        if self._inputs is None:
            self._inputs = tuple(inputs)
            _check_columns(self._spec, self._measured or (), self._inputs)
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._inp.append(tuple(inputs.values()))
        self._ann.append(self._pending)
        self._pending = {}
        self._meas.append(self._row(info))
        self._ep_meta["terminated"] = bool(terminated)
        self._ep_meta["truncated"] = bool(truncated)
        return obs, reward, terminated, truncated, info

    def to_log(self, *, include_unfinished: bool = True, min_rows: int = 2) -> TrialLog:
        """The recorded episodes as a :class:`~vesselid.data.logs.TrialLog`.

        Parameters
        ----------
        include_unfinished : bool, default True
            Include the running episode (its rows that have an input).
        min_rows : int, default 2
            Skip episodes with fewer rows (identification needs two consecutive rows).

        Returns
        -------
        TrialLog
            Columns ``experiment, time``, the spec's states, inputs and sensors, then the
            environment's extra columns (``true_*``, ...). Metadata: ``spec``,
            ``vesselid_version``, ``seed`` (of the first reset), ``reset_seeds``,
            ``env_id``, ``env_kwargs``, ``env_class``, ``env_settings``, ``episodes``
            (per experiment: seed, steps, terminated, truncated, and finished: whether
            the episode ended with ``terminated`` or ``truncated`` rather than being cut
            by a ``reset`` or still running).

        Raises
        ------
        VesselidError
            Nothing has been recorded.
        """
        episodes = [dict(e, finished=bool(e["terminated"] or e["truncated"]))
                    for e in self._episodes]
        if include_unfinished and self._open:
            n = len(self._inp)
            finished = self._ep_meta["terminated"] or self._ep_meta["truncated"]
            episodes.append({"meas": self._meas[:n], "inp": self._inp, "ann": self._ann,
                             **self._ep_meta, "steps": n, "finished": bool(finished)})
        episodes = [e for e in episodes if len(e["inp"]) >= max(1, int(min_rows))]
        if not episodes or self._measured is None or self._inputs is None:
            raise VesselidError("no episode with enough recorded steps to build a trial log")
        _check_columns(self._spec, self._measured, self._inputs)
        meas = np.concatenate([np.asarray(e["meas"], dtype=np.float64) for e in episodes])
        inp = np.concatenate([np.asarray(e["inp"], dtype=np.float64) for e in episodes])
        exp = np.concatenate([np.full(len(e["inp"]), i) for i, e in enumerate(episodes)])
        k = np.concatenate([np.arange(len(e["inp"])) for e in episodes])
        dt = _sample_time(self.env.unwrapped, self._spec)
        data = _frame(self._spec, dt, self._measured, self._inputs, exp, k, meas, inp)
        keys = list(dict.fromkeys(key for e in episodes for a in e["ann"] for key in a))
        clash = [c for c in keys if c in data.columns]
        if clash:
            raise VesselidError(f"annotated columns {clash} clash with the log's columns")
        for key in keys:
            data[key] = np.array([a.get(key, np.nan) for e in episodes for a in e["ann"]],
                                 dtype=np.float64)
        ep_meta = [
            {"experiment": i,
             **{key: v for key, v in e.items() if key not in ("meas", "inp", "ann")}}
            for i, e in enumerate(episodes)
        ]
        meta = _metadata(self.env, self.env.unwrapped, self._spec, self._seeds, ep_meta)
        if self._closed_loop is not None:
            meta["closed_loop"] = self._closed_loop
        return TrialLog(data, meta)

    def save(self, path: str | Path, **kwargs: Any) -> Path:
        """Write :meth:`to_log` to ``path`` (``.csv`` + JSON sidecar, or ``.parquet``)."""
        return self.to_log(**kwargs).save(path)


# ---------------------------------------------------------------------- vector env
class VectorTrialRecorder(gym.vector.VectorWrapper):
    """Record the episodes of every sub-environment of a vector environment.

    Parameters
    ----------
    env : gymnasium.vector.VectorEnv
        A vector environment whose ``unwrapped`` implements the recorder contract, with
        ``NEXT_STEP`` or ``SAME_STEP`` autoreset, e.g.
        ``gym.make_vec("vesselid/Heave-v0", 64, vectorization_mode="vector_entry_point")``.

    Notes
    -----
    Storage is one ``(num_envs, columns)`` array per step; episodes are assembled
    (vectorised) only in :meth:`to_log`. Experiments are numbered in the order the
    episodes started (sub-environment index breaks ties).
    """

    def __init__(self, env: gym.vector.VectorEnv) -> None:
        super().__init__(env)
        self._spec = _contract(env.unwrapped)
        mode = env.metadata.get("autoreset_mode", AutoresetMode.NEXT_STEP)
        if isinstance(mode, str):
            mode = AutoresetMode(mode)
        if mode not in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP):
            raise VesselidError(
                f"VectorTrialRecorder supports NEXT_STEP and SAME_STEP autoreset, got {mode}"
            )
        self._mode = mode
        self._measured: tuple[str, ...] | None = None
        self._inputs: tuple[str, ...] | None = None
        self.clear()

    def clear(self) -> None:
        """Forget everything recorded; recording restarts at the next ``reset``."""
        n = self.num_envs
        self._M: list[np.ndarray] = []  # (n, n_meas) per row time
        self._E: list[np.ndarray] = []  # (n,) episode id per row time
        self._U: list[np.ndarray] = []  # (n, n_inputs): input of row t
        self._V: list[np.ndarray] = []  # (n,) bool: row t has an input
        self._ep_ids = np.full(n, -1, dtype=np.int64)
        self._next_id = 0
        self._prev_done = np.zeros(n, dtype=np.bool_)
        self._ep_env: list[int] = []
        self._ep_seed: list = []
        self._ep_term: dict[int, bool] = {}
        self._ep_trunc: dict[int, bool] = {}
        self._seeds: list = []

    @property
    def model_spec(self) -> ModelSpec:
        """Identification structure of the recorded data."""
        return self._spec

    @property
    def num_episodes(self) -> int:
        """Episodes started so far."""
        return self._next_id

    def _row(self, info: dict[str, Any]) -> np.ndarray:
        row = self.env.unwrapped.log_row(info)
        keys = tuple(row)
        self._measured = _same_columns(keys, self._measured)
        n = self.num_envs
        out = np.empty((n, len(keys)))
        for j, v in enumerate(row.values()):
            out[:, j] = v
        return out

    def _new_ids(self, mask: np.ndarray, seed: Any = None) -> None:
        idx = np.flatnonzero(mask)
        ids = np.arange(self._next_id, self._next_id + idx.size, dtype=np.int64)
        self._ep_ids = self._ep_ids.copy()
        self._ep_ids[idx] = ids
        self._next_id += idx.size
        self._ep_env.extend(int(i) for i in idx)
        self._ep_seed.extend([seed] * idx.size)

    def _mark_end(self, done: np.ndarray, terminated: Any, truncated: Any) -> None:
        for i in np.flatnonzero(done):
            eid = int(self._ep_ids[i])
            self._ep_term[eid] = bool(terminated[i])
            self._ep_trunc[eid] = bool(truncated[i])

    def reset(
        self, *, seed: int | list[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        n = self.num_envs
        if len(self._U) < len(self._M):  # the open rows get no input: dropped
            self._U.append(np.zeros((n, len(self._inputs or ()))))
            self._V.append(np.zeros(n, dtype=np.bool_))
        self._seeds.append(_jsonable(seed))
        self._new_ids(np.ones(n, dtype=np.bool_), _jsonable(seed))
        self._prev_done = np.zeros(n, dtype=np.bool_)
        self._M.append(self._row(info))
        self._E.append(self._ep_ids)
        return obs, info

    def step(self, actions: Any) -> tuple[Any, Any, Any, Any, dict[str, Any]]:
        if not self._M:
            raise VesselidError("call reset() before step() on a VectorTrialRecorder")
        n = self.num_envs
        inputs = self.env.unwrapped.log_inputs(actions)
        if self._inputs is None:
            self._inputs = tuple(inputs)
            _check_columns(self._spec, self._measured or (), self._inputs)
        u = np.empty((n, len(inputs)))
        for j, v in enumerate(inputs.values()):
            u[:, j] = v
        obs, reward, terminated, truncated, info = self.env.step(actions)
        done = np.logical_or(terminated, truncated)
        self._U.append(u)
        if self._mode is AutoresetMode.NEXT_STEP:
            # envs done at the previous step were reset: their open row had no input
            self._V.append(~self._prev_done)
            if self._prev_done.any():
                self._new_ids(self._prev_done)
            self._mark_end(done, terminated, truncated)
        else:  # SAME_STEP: a done env's returned observation starts its next episode
            self._V.append(np.ones(n, dtype=np.bool_))
            self._mark_end(done, terminated, truncated)
            if done.any():
                self._new_ids(done)
        self._prev_done = done
        self._M.append(self._row(info))
        self._E.append(self._ep_ids)
        return obs, reward, terminated, truncated, info

    def to_log(self, *, include_unfinished: bool = True, min_rows: int = 2) -> TrialLog:
        """The recorded episodes as a :class:`~vesselid.data.logs.TrialLog`.

        Parameters and returned columns as :meth:`TrialRecorder.to_log`; the metadata's
        ``episodes`` also give each experiment's ``env_index``.
        """
        if not self._U or self._measured is None or self._inputs is None:
            raise VesselidError("no episode with enough recorded steps to build a trial log")
        _check_columns(self._spec, self._measured, self._inputs)
        t_rows = len(self._U)  # rows with a decided input (the open rows are excluded)
        meas = np.stack(self._M[:t_rows])  # (T, n, m)
        eps = np.stack(self._E[:t_rows])  # (T, n)
        inp = np.stack(self._U)  # (T, n, p)
        valid = np.stack(self._V)  # (T, n)
        t_idx = np.broadcast_to(np.arange(t_rows)[:, None], eps.shape)
        sel = valid.ravel()
        ep = eps.ravel()[sel]
        t = t_idx.ravel()[sel]
        order = np.lexsort((t, ep))
        ep, t = ep[order], t[order]
        meas_v = meas.reshape(-1, meas.shape[-1])[sel][order]
        inp_v = inp.reshape(-1, inp.shape[-1])[sel][order]
        uniq, start, counts = np.unique(ep, return_index=True, return_counts=True)
        k = t - np.repeat(t[start], counts)
        finished = np.array([u in self._ep_term for u in uniq], dtype=np.bool_)
        keep = counts >= max(1, int(min_rows))
        if not include_unfinished:
            keep &= finished
        if not keep.any():
            raise VesselidError("no episode with enough recorded steps to build a trial log")
        rows = np.repeat(keep, counts)
        new_id = np.cumsum(keep) - 1
        experiment = np.repeat(new_id, counts)[rows]
        dt = _sample_time(self.env.unwrapped, self._spec)
        data = _frame(self._spec, dt, self._measured, self._inputs, experiment, k[rows],
                      meas_v[rows], inp_v[rows])
        episodes = []
        for j in np.flatnonzero(keep):
            eid = int(uniq[j])
            episodes.append({
                "experiment": int(new_id[j]),
                "env_index": self._ep_env[eid],
                "seed": self._ep_seed[eid],
                "steps": int(counts[j]),
                "terminated": self._ep_term.get(eid, False),
                "truncated": self._ep_trunc.get(eid, False),
                "finished": bool(finished[j]),
            })
        meta = _metadata(self.env, self.env.unwrapped, self._spec, self._seeds, episodes)
        meta["num_envs"] = int(self.num_envs)
        return TrialLog(data, meta)

    def save(self, path: str | Path, **kwargs: Any) -> Path:
        """Write :meth:`to_log` to ``path`` (``.csv`` + JSON sidecar, or ``.parquet``)."""
        return self.to_log(**kwargs).save(path)


def _same_columns(keys: tuple[str, ...], earlier: tuple[str, ...] | None) -> tuple[str, ...]:
    """``log_row`` must return the same columns on every call (recorder contract)."""
    if earlier is not None and keys != earlier:
        raise VesselidError(f"log_row returned columns {list(keys)}, earlier {list(earlier)}")
    return keys
