"""A model's parameters, kept once made, are those it would make: equal to the plain entries of
its fields every call, a new dict each time (a caller that changes one changes no other), and
the same in a pickled copy; entries that are not plain scalars (lists) are made afresh."""

import math
import pickle

import numpy as np
import pytest

import bananagrid as bg
from bananagrid.models.params import plain_parameters

MODELS = {
    "polar": bg.PolarBanana(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54, sigma_heading=0.05,
                            pose=bg.Pose(origin=(10.0, -20.0), heading=0.3)),
    "cat": bg.CAT(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54),
    "bearing": bg.BearingFix(sensors=[(0.0, 0.0), (4000.0, 0.0)], bearings=[0.6, -0.5], sigmas=[0.01, 0.02]),
    "butterly": bg.Butterly(mean=(0.0, 500.0), cov=[[1e4, 2e3], [2e3, 2.5e4]], speeds=[1.0, 1.5],
                            weights=[0.5, 0.5], t=600.0),
    "mixture": bg.GaussianMixture(weights=[0.4, 0.6], means=[[0.0, 0.0], [50.0, 10.0]],
                                  covs=[np.eye(2) * 100.0, np.eye(2) * 400.0]),
}


@pytest.mark.parametrize("name", list(MODELS))
def test_kept_parameters_are_the_models_own(name):
    model = MODELS[name]
    first = model.parameters()
    plain = plain_parameters(model)
    assert {k: first[k] for k in plain} == plain  # the fields' entries, then any the model adds
    first["model"] = "changed"
    for value in first.values():
        if isinstance(value, list):
            value.append("changed")
    second = model.parameters()
    assert second is not first and second == model.parameters()
    assert second["model"] == type(model).__name__
    assert all("changed" not in v for v in second.values() if isinstance(v, list))
    assert pickle.loads(pickle.dumps(model)).parameters() == second


def test_a_fix_adds_its_point():
    model = MODELS["bearing"]
    fix = model.parameters()
    assert set(fix) - set(plain_parameters(model)) == {"fix_x", "fix_y"}
    assert all(type(fix[k]) is float and math.isfinite(fix[k]) for k in ("fix_x", "fix_y"))
