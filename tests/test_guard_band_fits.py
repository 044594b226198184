"""The likelihood fits of ``auto``'s colour-test guard band: the sensor-noise model alone
for the groups the band sends, every model and the joint stage for the others, the
arrays of one call over all groups."""

import numpy as np

from vesselid.identify import from_arrays, pem
from vesselid.identify.efficient import _guard_band_fits
from vesselid.identify.estimators import estimate
from vesselid.plant.systems import heave


def _batch(runs=3, samples=3000, seed=5):
    system = heave()
    spec = system.identification_spec(aggregate=False)
    sim = system.simulate(samples, n_runs=runs, seed=seed)
    data = from_arrays(spec, sim.y, sim.u)
    base = estimate(data, spec, "iv-zero-mean", combine="pooled")
    return data, spec, base.theta


def _same(a, b, keys):
    for key in keys:
        if a[key].dtype == object:
            assert list(a[key]) == list(b[key]), key
        else:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def test_guard_band_groups_fit_the_sensor_model_alone_and_the_others_every_model():
    from vesselid.identify.efficient import _subset

    data, spec, theta = _batch()
    band = np.array([True, False, True])
    got = _guard_band_fits(data, spec, theta, band, "auto")
    full = pem.fit_groups(_subset(data, ~band), spec, theta[~band], joint=True,
                          boundary="auto")
    alone = pem.fit_groups(_subset(data, band), spec, theta[band], models=("sensor",),
                           joint=False)
    keys = [k for k in full if k != "loglik"]
    _same({k: v[~band] for k, v in got.items()}, full, keys)
    _same({k: v[band] for k, v in got.items()}, alone, keys)
    sensor = pem.DISTURBANCE_MODELS.index("sensor")
    np.testing.assert_array_equal(got["loglik"][~band], full["loglik"])
    np.testing.assert_array_equal(got["loglik"][band, sensor], alone["loglik"][:, 0])
    assert np.isnan(got["loglik"][band, 1 - sensor]).all()
    assert set(got["model"][band]) <= {"sensor"}  # no joint stage in the band
    # no group in the band: one call over every group, as before the guard
    _same(_guard_band_fits(data, spec, theta, np.zeros(3, bool), "auto"),
          pem.fit_groups(data, spec, theta, joint=True, boundary="auto"), list(full))
