"""The engine's hook for carried evidence: what it refuses, in one line each, and the shapes
and dtypes it returns."""

from __future__ import annotations

import math

import numpy as np
import pytest

import bananagrid as bg
from bananagrid.engine.carried import carries, evaluate_carried, weigh_paths
from bananagrid.evidence.packing import pack
from cases import FIG1

PACK = pack([bg.AreaSearch([(-300.0, 900.0), (300.0, 900.0), (300.0, 1400.0), (-300.0, 1400.0)], t=4.0, pod=0.5)],
            FIG1["t"])


def test_shapes_and_dtypes():
    model = bg.CAT(**FIG1)
    x = np.zeros((2, 3))
    y = np.linspace(2000.0, 2800.0, 3)
    for dtype in (np.float64, np.float32):
        out = evaluate_carried(model, x, y, PACK, dtype=dtype)
        assert out.shape == (PACK.channels.shape[0], 2, 3) and out.dtype == dtype
        assert np.all(out[PACK.channel("all")] <= out[PACK.channel("prior")] * (1 + 1e-6))
    assert evaluate_carried(model, [], [], PACK).shape == (PACK.channels.shape[0], 0)
    assert carries(model) and not carries(bg.PolarBanana(**FIG1))


@pytest.mark.parametrize("call, message", [
    (lambda: evaluate_carried(bg.PolarBanana(**FIG1), [0.0], [0.0], PACK),
     r"^model = PolarBanana: its kernels do not carry evidence along its paths$"),
    (lambda: evaluate_carried(bg.CAT(**FIG1), [0.0, math.nan], [0.0, 1.0], PACK), r"^x, y: points must be finite"),
    (lambda: evaluate_carried(bg.CAT(**FIG1), np.zeros(3), np.zeros(2), PACK), r"^x and y: shapes \(3,\) and \(2,\)"),
    (lambda: weigh_paths(PACK, np.zeros((4, 3, 2)), np.ones(4)), r"^positions: shape \(4, 3, 2\); expected \(n, 1, 2\)"),
])
def test_refused_in_one_line(call, message):
    with pytest.raises(bg.BananagridError, match=message) as caught:
        call()
    assert "\n" not in str(caught.value)
