"""The CAT root search's derivatives (``kernels/cat.py``: ``cat_eval_curved``): dF/domega,
d^2F/domega^2, d^3F/domega^3 and the line's acceleration with two derivatives, against central
differences of the kernel's own lower derivative, on both sides of the basis' series switch
(|omega t| = 1) and across turns. Halley's step and the proof that ends the search at the Halley
point (``cat_root_step``) rest on them; the density carried there rests on a' and a''."""

import numpy as np
import pytest
import warp as wp

from bananagrid.kernels import cat

#: (v0, t, x, y): the Figure 1 CAT's speed and time (paper Figure 1), a point on its banana and
#: one beside it; a slow long run (many turns over the scanned turn rates).
POINTS = [(280.0, 10.0, 150.0, 2600.0), (280.0, 10.0, -900.0, 1800.0), (0.5, 600.0, 40.0, -120.0)]
#: Turn rates as omega t: inside the series' range, at its switch, beyond it, several turns.
TURNS = [0.003, 0.4, 0.999, 1.001, 2.5, -4.0, 17.0]


@wp.kernel
def _derivatives(v0: wp.float64, t: wp.float64, x: wp.float64, y: wp.float64, ws: wp.array(dtype=wp.float64),
                 out: wp.array2d(dtype=wp.float64)):
    i = wp.tid()
    f, df, ddf, dddf, acc, dacc, ddacc = cat.cat_eval_curved(x, y, ws[i], v0, t)
    out[i, 0] = f
    out[i, 1] = df
    out[i, 2] = ddf
    out[i, 3] = dddf
    out[i, 4] = acc
    out[i, 5] = dacc
    out[i, 6] = ddacc


@pytest.mark.parametrize("point", POINTS)
def test_each_derivative_is_the_difference_quotient_of_the_one_below(point):
    v0, t, x, y = point
    omegas = np.array(TURNS) / t
    h = 1e-4 / t  # central differences: error (h^2 / 6) f''' ~ 1e-9 relative at omega t ~ 1
    ws = np.stack([omegas - h, omegas, omegas + h], axis=1).ravel()
    out = wp.zeros((ws.size, 7), dtype=wp.float64, device="cpu")
    wp.launch(_derivatives, dim=ws.size, device="cpu", inputs=[v0, t, x, y, wp.array(ws, dtype=wp.float64), out])
    values = out.numpy().reshape(len(omegas), 3, 7)
    quotient = (values[:, 2] - values[:, 0]) / (2.0 * h)
    at = values[:, 1]
    for lower, upper in ((0, 1), (1, 2), (2, 3), (4, 5), (5, 6)):
        scale = np.abs(at[:, upper]).max()  # the derivative's size over the turns: its zeros aside
        # 1e-6 of that: the quotient's truncation (~1e-9) and rounding (eps |f| / h ~ 1e-10) far inside
        np.testing.assert_allclose(quotient[:, lower], at[:, upper], rtol=0.0, atol=1e-6 * scale,
                                   err_msg=f"column {upper}")
