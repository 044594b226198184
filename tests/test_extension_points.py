"""Adding a vessel, a disturbance or an estimator is one module plus one registry line.

Each toy below is the "one module" (defined here, importable as this test module), and each
``register_*`` call is the one line; the test then uses the toy through the public API and
the command line as a user would.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from vesselid.plant.disturbances import Process, process_from_dict
from vesselid.plant.vessels.hull import Hull

# ------------------------------------------------------------------ a toy vessel module
#: A barge with linear and quadratic damping only (made-up coefficients).
HULL = Hull.from_table(
    "toy-barge",
    np.diag([200.0, 250.0, 80.0]),
    {
        "u": {"u": -10.0, "u*|u|": -40.0, "X": 1.0},
        "v": {"v": -20.0, "v*|v|": -90.0, "Y": 1.0},
        "r": {"r": -15.0, "N": 1.0},
    },
    length=4.0,
    beam=2.0,
    force_max=(60.0, 30.0, 15.0),
    description="toy barge (test)",
)


def system(*, dt: float = 0.1):
    from vesselid.plant.vessels.system import pulse_system

    return pulse_system(HULL, {"X": (10.0, 40.0), "Y": (-20.0, 20.0),
                               "N": ((2.0, 10.0), (-10.0, -2.0))}, dt=dt,
                        process_noise_std=(1e-3, 1e-3, 1e-4), process_noise_time_constant=2.0,
                        sensor_noise_std=(0.01, 0.01, 0.001), x0=(0.3, 0.0, 0.0),
                        description=HULL.description)


# ------------------------------------------------------------- a toy disturbance module
class Telegraph(Process):
    """A random telegraph current: ±``level``, switching sign with probability ``p``."""

    def __init__(self, level: float, p: float) -> None:
        self.level, self.p = float(level), float(p)

    @property
    def std(self) -> float:
        return self.level

    @property
    def mean(self) -> float:
        return 0.0

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        flips = rng.random(n) < self.p
        sign = np.where(np.cumsum(flips) % 2 == 0, 1.0, -1.0)
        return self.level * sign * (1.0 if rng.random() < 0.5 else -1.0)

    def to_dict(self) -> dict:
        return {"kind": "toy-telegraph", "level": self.level, "p": self.p}


# -------------------------------------------------------------- a toy estimator module
def _toy_class():
    from vesselid.identify.methods import LeastSquares

    class ToyLeastSquares(LeastSquares):
        name = "toy-ls"
        label = "least squares under another name (test)"
        short = "toy"
        plot_label = "toy"

    return ToyLeastSquares


ToyLeastSquares = _toy_class()


@pytest.fixture
def registries():
    """Undo the registrations after each test."""
    from vesselid.identify import registry
    from vesselid.plant import catalogue, disturbances

    saved = (dict(catalogue.VESSELS), dict(catalogue.SYSTEMS), dict(disturbances._KINDS),
             dict(registry._ENTRIES), dict(registry._BUILT))
    yield
    catalogue.VESSELS.clear(); catalogue.VESSELS.update(saved[0])  # noqa: E702
    catalogue.SYSTEMS.clear(); catalogue.SYSTEMS.update(saved[1])  # noqa: E702
    disturbances._KINDS.clear(); disturbances._KINDS.update(saved[2])  # noqa: E702
    registry._ENTRIES.clear(); registry._ENTRIES.update(saved[3])  # noqa: E702
    registry._BUILT.clear(); registry._BUILT.update(saved[4])  # noqa: E702


def test_a_new_vessel_is_one_module_and_one_line(registries) -> None:
    from vesselid.plant import catalogue

    catalogue.register_vessel("toy-barge", __name__)

    assert catalogue.get_hull("toy-barge") is HULL
    sim = catalogue.get_system("toy-barge").simulate(400, n_runs=1, seed=1)
    frame = sim.to_log().to_frame()
    assert {"u", "v", "r", "X", "Y", "N"} <= set(frame.columns)
    assert np.isfinite(frame[["u", "v", "r"]].to_numpy()).all()

    gym = pytest.importorskip("gymnasium")
    import vesselid.envs  # noqa: F401

    env = gym.make("vesselid/Manoeuvring3DOF-v0", vessel="toy-barge")
    obs, _ = env.reset(seed=0)
    obs, *_ = env.step(np.zeros(3, dtype=np.float32))
    assert np.isfinite(obs).all()
    env.close()


def test_a_new_disturbance_is_one_module_and_one_line(registries) -> None:
    from vesselid.plant.catalogue import get_system
    from vesselid.plant.disturbances import register_process

    register_process("toy-telegraph", lambda d: Telegraph(d["level"], d["p"]))

    plant = replace(get_system("heave"), current={"w": Telegraph(0.05, 0.02)})
    log = plant.simulate(2000, n_runs=1, seed=2).to_log()
    truth = log.to_frame()["true_current_w"].to_numpy()
    assert set(np.round(np.abs(truth), 12)) == {0.05}
    rebuilt = process_from_dict(Telegraph(0.05, 0.02).to_dict())
    assert isinstance(rebuilt, Telegraph) and rebuilt.p == 0.02


def test_a_new_estimator_is_one_module_and_one_line(registries, tmp_path) -> None:
    from vesselid.cli import main
    from vesselid.identify import identify
    from vesselid.identify.registry import ESTIMATORS, EstimatorEntry, names, register
    from vesselid.plant.catalogue import get_system

    register(EstimatorEntry("toy-ls", f"{__name__}:ToyLeastSquares", streamable=False))

    assert "toy-ls" in names() and "toy-ls" in ESTIMATORS
    log = get_system("heave").simulate(3000, n_runs=1, seed=4).to_log()
    toy = identify(log, None, "toy-ls")
    ls = identify(log, None, "ls")
    assert toy.method == "toy-ls"
    np.testing.assert_array_equal(toy.params.to_numpy(), ls.params.to_numpy())

    path = tmp_path / "trial.parquet"
    log.save(path)
    assert main(["identify", str(path), "--method", "toy-ls"]) == 0
    assert main(["identify", str(path), "--method", "no-such-estimator"]) == 2


def test_a_registry_entry_must_name_its_class_right(registries) -> None:
    from vesselid.errors import IdentificationError
    from vesselid.identify.registry import EstimatorEntry, get_estimator, register

    register(EstimatorEntry("not-toy", f"{__name__}:ToyLeastSquares"))
    with pytest.raises(IdentificationError, match="registered as 'not-toy'"):
        get_estimator("not-toy")
    register(EstimatorEntry("bad-target", "vesselid.identify.methods"))
    with pytest.raises(IdentificationError, match="not 'module:Class'"):
        get_estimator("bad-target")


def test_a_new_disturbance_reaches_every_user_of_the_plant(registries) -> None:
    """A registered process kind, as a force on the vessel (``ProcessForce``), moves the
    simulated trial and the trial planner's disturbed paths and prediction with no edit
    of either; the settings round-trip through metadata. On a heave ``System`` the same
    process as a current moves its disturbed paths."""
    from vesselid.plant.catalogue import get_system
    from vesselid.plant.disturbances import register_process
    from vesselid.plant.plant import Plant
    from vesselid.plant.vessels import ProcessForce, VesselDisturbances, simulate_vessel
    from vesselid.studies.planner import DisturbanceLevels, predict_design

    register_process("toy-telegraph", lambda d: Telegraph(d["level"], d["p"]))
    force = ProcessForce(Telegraph(0.3, 0.01), gain=(0.0, 1.0, 0.2))
    calm = DisturbanceLevels(force_noise_std=(0.0, 0.0, 0.0), wind_speed=0.0, gust_std=0.0,
                             wind_direction_std=0.0)
    levels = replace(calm, components=(force,))
    plant = levels.plant()
    assert isinstance(plant, Plant)
    n = 800
    forces = np.tile([1.5, 0.0, 0.0], (n, 1))
    paths = plant.disturbed_paths(forces, paths=2, seed=4)
    # the documented order: the three unmodelled forces (one block), then the component
    rng = np.random.default_rng(4)
    for path in paths:
        rng.standard_normal((3, n))
        rng.standard_normal(3)
        tau = forces + force.draw(rng, n, plant.dt).force
        np.testing.assert_array_equal(path, plant.run(tau))
    assert np.abs(paths[:, :, 1]).max() > 1e-3  # the sway force moves the vessel
    assert np.array_equal(calm.plant().disturbed_paths(forces, paths=1, seed=4)[0],
                          plant.run(forces))
    # the planner's prediction follows (cross moment over the disturbed paths)
    sched = np.concatenate([forces, np.tile([1.5, 1.0, -0.5], (n, 1)),
                            np.tile([1.0, -1.0, 0.5], (n, 1))])[None]
    a = predict_design(sched, levels=calm, estimator="iv-zero-mean", paths=2)
    b = predict_design(sched, levels=levels, estimator="iv-zero-mean", paths=2)
    assert not np.allclose(a.cov.to_numpy(), b.cov.to_numpy(), rtol=1e-6, atol=0)
    # the simulated trial: the same component among the vessel's disturbances
    dist = VesselDisturbances(components=(force,))
    sim = simulate_vessel(plant.hull, forces, seed=1, disturbances=dist)
    meta = sim.to_log().metadata
    rebuilt = ProcessForce.from_dict(meta["system"]["disturbances"]["components"][0])
    assert isinstance(rebuilt.process, Telegraph) and rebuilt.gain == force.gain
    again = ProcessForce.from_dict(levels.to_dict()["components"][0])
    assert again.process.to_dict() == force.process.to_dict()
    # a System: the same kind as a current on the heave vehicle
    heave = replace(get_system("heave"), current={"w": Telegraph(0.05, 0.02)})
    assert isinstance(heave, Plant)
    u = np.full((500, 1), 0.2)
    hp = heave.disturbed_paths(u, paths=1, seed=3)[0]
    assert hp.shape == (501, 1) and not np.allclose(hp, heave.run(u))
