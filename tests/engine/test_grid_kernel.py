"""The grid kernels that sum their own rows (``DensityKernels.row_sums``: the polar lane kernels):
the captured mass from the kernel's row sums, against the sums of the values it returned."""

import math
import warnings

import numpy as np
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid.engine.warp_runtime import row_sums
from bananagrid.kernels import polar_lanes


@seed(20261127)
@settings(max_examples=40, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(nx=st.integers(1, 200), ny=st.integers(1, 40), variant=st.sampled_from(["rough", "improved"]),
       sigma_heading=st.sampled_from([0.0, 0.05]), dtype=st.sampled_from([np.float64, np.float32]),
       reach=st.floats(0.2, 2.0), threads=st.sampled_from([1, 2, 3]))
def test_the_mass_is_the_sum_of_the_values_returned(nx, ny, variant, sigma_heading, dtype, reach, threads):
    """Rows of every width (a partial vector of lanes at the end of most: its unused lanes must
    not count), both variants, with heading noise (rows the generated kernel sums) and without
    (rows the native row loop sums), both dtypes, any thread count: the mass is the sum of the
    values within float64 summation error, and the same bits for every thread count."""
    assert polar_lanes.KERNELS.row_sums
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a grid that misses mass warns
        model = bg.PolarBanana(v0=200.0, t=10.0, sigma_a=5.0, sigma_omega=0.06, variant=variant,
                               sigma_heading=sigma_heading)
        grid = bg.Grid.from_bounds(x=(-2000.0 * reach, 2000.0 * reach), y=(-200.0, 2000.0 * reach + 200.0),
                                   dx=4000.0 * reach / nx, dy=(2000.0 * reach + 400.0) / ny)
        raster = bg.rasterise(model, grid, dtype=dtype, threads=threads)
        one = bg.rasterise(model, grid, dtype=dtype, threads=1)
    assert raster.values.shape == (ny, nx)
    expected = math.fsum(row_sums(raster.values).tolist()) * grid.cell_area
    # both are float64 sums of the same nonnegative values, each row in its own order (the
    # kernel's by lane position, NumPy's pairwise): each within (nx - 1) eps = 4.4e-14 of the
    # exact sum for nx <= 200; the rows' sums are added exactly
    assert raster.mass == 0.0 if expected == 0.0 else abs(raster.mass - expected) <= 1e-13 * expected
    assert raster.mass == one.mass
