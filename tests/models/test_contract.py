"""The model contract: every registered model kind through the same checks (in the manner of
SciPy's ``test_continuous_basic.py``), and a model defined only in the tests through all of them
plus scenes and recordings.

One table of cases, one per model kind and setting, whose checks follow the kind's domain in
the registry. A grid kind's case has scene parameters, a grid holding its mass, a polar lattice
over its support and bad values with the messages they must give; its checks: ``pdf`` equals
``rasterise``; the thread count changes nothing; float32 within the model's stated
``float32_rtol``; Monte Carlo from the model's own ``sample``; polar-lattice cells that sum to
the grid's mass; radial moments along rays; every bad value refused with its name. An array
kind's case (a presence law) has its parameters, an angular lattice and a room; the same checks
in its domain: ``pdf`` in the protocol's form against its closed form; the lattice's cells from
``rasterise`` equal the law's own; the thread count changes nothing; float32 within the stated
bound; Monte Carlo of the law's own samples binned by direction; the cells sum to the law's own
probability of the room's part that the lattice sees; every bad value refused with its name.
"""

import math
import sys
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

import bananagrid as bg
from bananagrid.engine.warp_runtime import WarpContext
from bananagrid.domains.pose import Pose
from bananagrid.recording.inspect import inspect_recording
from bananagrid.scenes.load import parse_scene
from bananagrid.scenes.run import run_scene

from bananagrid.protocol import CellPlan, PresenceModel
from cases import FIG1, FIG1_BOUNDS
from isotropic_model import ISOTROPIC, IsotropicNormal
from presence_oracle import bin_samples

from bananagrid.models.registry import ENTRY_POINT_GROUP, kinds_from_entry_points

#: The tests' own installed package (tests/plugins: a model registered by entry point).
PLUGINS = Path(__file__).resolve().parents[1] / "plugins"


def plugin_kinds() -> bg.models.registry.Registry:
    """The registry with the kinds of the distributions in ``tests/plugins``, loaded through
    their entry points as an installed package's are; the directory is on ``sys.path`` only
    while they import, so that no other test finds the distribution."""
    entries = [e for dist in metadata.distributions(path=[str(PLUGINS)])
               for e in dist.entry_points.select(group=ENTRY_POINT_GROUP)]
    sys.path.insert(0, str(PLUGINS))
    try:
        return kinds_from_entry_points(bg.MODEL_KINDS, entries)
    finally:
        sys.path.remove(str(PLUGINS))

COASTAL = dict(sensors=[(0.0, 0.0), (20000.0, 0.0)], bearings=[0.2641, -0.3909], sigmas=[0.01, 0.02])
BUTTERLY = dict(mean=(0.0, 0.0), cov=[[4e4, 5e3], [5e3, 2.5e4]], speeds=[1.0, 2.0], weights=[0.4, 0.6], t=600.0)
FULL_TURN = dict(bearings=(-math.pi, math.pi), bearing_step=math.radians(5.0))


@dataclass(frozen=True)
class Case:
    kind: str
    params: dict
    bounds: dict  # grid bounds (x, y) holding the model's mass
    step: float  # grid step, m
    lattice: dict  # PolarLattice arguments over the model's support
    bad: tuple = ()  # (parameter, bad value, message regex)
    #: pdf against rasterise: 0 is bit for bit; Butterly's grid kernel sums its series about tile
    #: centres (a different summation order from the points kernel) and zeroes cells it proves
    #: below 1e-13 of the peak: 1e-11 relative where the density exceeds 1e-12 of its maximum
    #: (its stated agreement, docs). Thread counts change no bit of any model.
    pdf_rtol: float = 0.0
    pose: dict | None = None  # pose of the rays for radial moments (None: the model's own)
    kinds: bg.models.registry.Registry = field(default=bg.MODEL_KINDS)

    def model(self, **changes):
        return self.kinds[self.kind].build({**self.params, **changes})

    @property
    def grid(self):
        return bg.Grid.from_bounds(**self.bounds, step=self.step)

    @property
    def domain(self) -> str:
        return self.kinds[self.kind].domain


@dataclass(frozen=True)
class ArrayCase:
    """A presence law of an ``"array"`` kind: its parameters (a uniform law's region as Region
    arguments), its angular lattice and the room S its cells are conditioned on."""

    kind: str
    params: dict
    lattice: dict  # AngularLattice arguments
    room: dict  # Region arguments of S
    bad: tuple = ()  # (parameter, bad value, message regex)
    kinds: bg.models.registry.Registry = field(default=bg.MODEL_KINDS)

    def model(self, **changes):
        return self.kinds[self.kind].build({**self.params, **changes})

    @property
    def angular(self):
        return bg.AngularLattice(**self.lattice)

    @property
    def region(self):
        return bg.Region(**self.room)

    @property
    def domain(self) -> str:
        return self.kinds[self.kind].domain


DEG = math.pi / 180.0
#: The room of the bundled room scenes (array frame, m) and room_mixture.toml's law.
ROOM = dict(x=(-3.0, 3.0), y=(-2.5, 2.5))
ROOM_MIXTURE = dict(weights=[0.5, 0.35, 0.15], means=[[-1.8, 1.5], [1.2, -1.8], [2.6, 1.9]],
                    covs=[np.diag([0.0625, 0.0625]), np.diag([0.49, 0.04]), [[0.0225, 0.0135], [0.0135, 0.09]]])
PLANE = dict(geometry="plane", h=1.8, azimuth_step=5 * DEG, elevation_step=5 * DEG)
MIXTURE_BAD = (
    ("weights", [0.5, 0.35, 0.25], r"weights = \[0.5, 0.35, 0.25\]: they sum to 1.1\d*, not 1"),
    ("covs", [[[1.0, 2.0], [2.0, 1.0]]] * 3, r"covs\[0\] = \[\[1.0, 2.0\], \[2.0, 1.0\]\]: must be positive definite "
                                             r"\(eigenvalues -1, 3; correlation 2; allowed: \|rho\| < 1"),
    ("means", [[0.0, 0.0, 0.0]] * 3, r"covs: expected shape \(3, 3, 3\) to match the means"),
)
MOTION_BAD = (
    ("v0", -1.0, r"v0 = -1.0: must be > 0"),
    ("sigma_a", math.nan, r"sigma_a = nan: must be finite"),
    ("sigma_omega", "0.1", r"sigma_omega = '0.1': expected a real number"),
    ("sigma_heading", -0.1, r"sigma_heading = -0.1: must be >= 0"),
)
CASES = {
    "cat": Case("cat", FIG1, FIG1_BOUNDS, 40.0, dict(ranges=(0.0, 4000.0), range_step=100.0, **FULL_TURN),
                bad=(*MOTION_BAD, ("k_sigma", 40.0, r"k_sigma = 40.0: must be in \[1, 38\]"))),
    "cat-heading": Case("cat", {**FIG1, "sigma_heading": math.pi / 30}, dict(x=(-3000.0, 3000.0), y=(-600.0, 3600.0)),
                        40.0, dict(ranges=(0.0, 4000.0), range_step=100.0, **FULL_TURN)),
    "cat-posed": Case("cat", {**FIG1, "origin": (500.0, -300.0), "heading": 0.7},
                      dict(x=(-1500.0, 4500.0), y=(-1800.0, 2800.0)), 40.0,
                      dict(ranges=(0.0, 4000.0), range_step=100.0, pose=Pose(origin=(500.0, -300.0), heading=0.7),
                           **FULL_TURN)),
    "polar-rough": Case("polar", {**FIG1, "variant": "rough"}, FIG1_BOUNDS, 40.0,
                        dict(ranges=(0.0, 4000.0), range_step=100.0, **FULL_TURN),
                        bad=(*MOTION_BAD, ("variant", "smooth", r"variant = 'smooth': must be one of rough, improved"))),
    "polar-heading": Case("polar", {**FIG1, "sigma_heading": math.pi / 15, "heading_order": 4},
                          dict(x=(-3200.0, 3200.0), y=(-800.0, 3600.0)), 40.0,
                          dict(ranges=(0.0, 4000.0), range_step=100.0, **FULL_TURN),
                          bad=(("heading_order", 3, r"heading_order = 3: must be 2"),)),
    "bearing_fix": Case("bearing_fix", COASTAL, dict(x=(2000.0, 14000.0), y=(24000.0, 36000.0)), 100.0,
                        dict(ranges=(20000.0, 40000.0), range_step=250.0, bearings=(0.0, 0.5), bearing_step=0.005),
                        bad=(("sigmas", [0.01, -0.02], r"sigmas\[1\] = -0.02: must be > 0"),
                             ("sensors", [(0.0, 0.0), (0.0, 0.0)], r"sensors 0 and 1 coincide"),
                             ("variant", "exact-ish", r"variant = 'exact-ish': must be one of exact, linear")),
                        pose=dict(origin=(0.0, 0.0), heading=0.26)),
    "bearing_fix-3": Case("bearing_fix", dict(sensors=[(0.0, 0.0), (20000.0, 0.0), (10000.0, -5000.0)],
                                              bearings=[0.2641, -0.3909, -0.05], sigmas=[0.01, 0.02, 0.02]),
                          dict(x=(2000.0, 14000.0), y=(24000.0, 36000.0)), 100.0,
                          dict(ranges=(20000.0, 40000.0), range_step=250.0, bearings=(0.0, 0.5), bearing_step=0.005),
                          pose=dict(origin=(0.0, 0.0), heading=0.26)),
    "butterly": Case("butterly", BUTTERLY, dict(x=(-2500.0, 2500.0), y=(-2500.0, 2500.0)), 50.0,
                     dict(ranges=(0.0, 2500.0), range_step=50.0, **FULL_TURN),
                     bad=(("t", -1.0, r"t = -1.0: must be >= 0"),
                          ("weights", [0.5, 0.6], r"weights = \[0.5, 0.6\]: must sum to 1"),
                          ("speeds", [1.0, -2.0], r"speeds\[1\] = -2.0: must be >= 0")),
                     pdf_rtol=1e-11, pose=dict(origin=(0.0, 0.0))),
    "butterly-course": Case("butterly", dict(mean=(0.0, 0.0), cov=[[1e4, 0.0], [0.0, 1e4]], speed_law="uniform",
                                             speed_min=0.5, speed_max=2.0, t=600.0, course_kappa=2.0,
                                             course_mean=0.5),
                            dict(x=(-1800.0, 1800.0), y=(-1800.0, 1800.0)), 40.0,
                            dict(ranges=(0.0, 1800.0), range_step=50.0, **FULL_TURN),
                            bad=(("course_kappa", -1.0, r"course_kappa = -1.0: must be >= 0"),),
                            pdf_rtol=1e-11, pose=dict(origin=(0.0, 0.0))),
    # the model of the tests, through exactly the same checks
    "isotropic": Case("isotropic", dict(mean=(300.0, -200.0), sigma=150.0), dict(x=(-700.0, 1300.0), y=(-1200.0, 800.0)),
                      20.0, dict(ranges=(0.0, 1200.0), range_step=40.0, pose=Pose(origin=(300.0, -200.0)), **FULL_TURN),
                      bad=(("sigma", 0.0, r"sigma = 0.0: must be > 0"),), pose=dict(origin=(300.0, -200.0)),
                      kinds=bg.MODEL_KINDS.with_kinds(ISOTROPIC)),
    # the constant-velocity model of the tests' installed package, by its entry point
    "cv": Case("cv", dict(mean=(0.0, 0.0), cov=[[4e4, 1e4], [1e4, 2.25e4]], velocity=(8.0, 4.0), q=50.0, t=120.0),
               dict(x=(-640.0, 2560.0), y=(-920.0, 1880.0)), 40.0,
               dict(ranges=(0.0, 1800.0), range_step=40.0, pose=Pose(origin=(960.0, 480.0)), **FULL_TURN),
               bad=(("q", -1.0, r"q = -1.0: must be >= 0"),
                    ("cov", [[1.0, 2.0], [2.0, 1.0]], r"cov = .*: must be positive definite")),
               pose=dict(origin=(960.0, 480.0)), kinds=plugin_kinds()),
    # presence laws on an array's angular cells (Pessentheiner), conditioned on a room
    "mixture-line": ArrayCase("mixture", dict(weights=[0.6, 0.4], means=[[-1.8], [2.6]], covs=[0.09, 0.04]),
                              dict(geometry="line", h=1.8, azimuth_step=2 * DEG), dict(x=(-3.0, 3.0)),
                              bad=(("weights", [0.6, 0.5], r"they sum to 1.1\d*, not 1"),
                                   ("covs", [-0.09, 0.04], r"covs\[0\] = \[\[-0.09\]\]: must be positive definite \(variances > 0\)"),
                                   ("means", [[-1.8, 0.0]], r"means: expected shape \(M, D\) with M = 2 components"))),
    "mixture-plane": ArrayCase("mixture", ROOM_MIXTURE, PLANE, ROOM, bad=MIXTURE_BAD),
    "mixture-frustum": ArrayCase("mixture", dict(weights=[0.5, 0.35, 0.15],
                                                 means=[[-1.8, 1.5, -1.75], [1.2, -1.8, -1.75], [2.6, 1.9, -1.35]],
                                                 covs=[np.diag([0.0625, 0.0625, 0.0025]), np.diag([0.49, 0.04, 0.0064]),
                                                       [[0.0225, 0.0135, 0.001], [0.0135, 0.09, 0.0], [0.001, 0.0, 0.0064]]]),
                                 dict(geometry="frustum", h=1.55, dh=0.25, azimuth_step=5 * DEG,
                                      elevation_step=5 * DEG), {**ROOM, "z": (-3.0, 0.0)},
                                 # x and y fully correlated: the correlation matrix's eigenvalues 0, 1, 2
                                 bad=(("covs", [[[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]]] * 3,
                                       r"covs\[0\] = .*: must be positive definite \(correlation eigenvalues .*; "
                                       r"condition number below 1e\+13\)"),
                                      ("covs", [[[1.0, 0.0, 0.0], [0.0, 1.0, 0.5], [0.0, 0.4, 1.0]]] * 3,
                                       r"covs\[0\] = .*: must be symmetric "
                                       r"\(covs\[0\]\[1\]\[2\] == covs\[0\]\[2\]\[1\]\)"))),
    "uniform-plane": ArrayCase("uniform", dict(region=ROOM), PLANE, dict(x=(-1.0, 3.0), y=(-2.5, 1.0)),
                               bad=(("region", "room", r"region = 'room': expected a bananagrid Region"),
                                    ("region", dict(x=(1.0, 0.0), y=(0.0, 1.0)), r"region x = \(1.0, 0.0\): the region is empty"))),
    "uniform-frustum": ArrayCase("uniform", dict(region={**ROOM, "z": (-3.0, 0.0)}),
                                 dict(geometry="frustum", h=1.55, dh=0.25, azimuth_step=5 * DEG, elevation_step=5 * DEG),
                                 {**ROOM, "z": (-3.0, 0.0)}),
}
GRID_CASES = [name for name, case in CASES.items() if case.domain == "grid"]


def assert_counts_follow(counts, expected):
    """Pearson's chi-square of sample counts against expected counts per cell, cells expecting
    fewer than 5 pooled into one, at level ALPHA."""
    big = expected >= 5
    obs = np.append(counts[big], counts[~big].sum())
    exp = np.append(expected[big], expected[~big].sum())
    if exp[-1] < 5:  # too little pooled mass for Pearson's approximation
        obs, exp = obs[:-1], exp[:-1] * (obs[:-1].sum() / exp[:-1].sum())
    chi2 = float(np.sum((obs - exp) ** 2 / exp))
    p_value = stats.chi2.sf(chi2, df=len(obs) - 1)
    assert p_value > ALPHA, f"chi2 = {chi2:.1f} on {len(obs) - 1} dof, p = {p_value:.2e}"
ARRAY_CASES = [name for name, case in CASES.items() if case.domain == "array"]


def test_every_registered_kind_has_a_case():
    """A kind added to the registry must join this table (and so pass every check here of its
    domain); a grid kind's model follows the density protocol, an array kind's the presence one."""
    assert set(bg.MODEL_KINDS) <= {case.kind for case in CASES.values()}
    assert set(GRID_CASES) | set(ARRAY_CASES) == set(CASES)
    assert all(isinstance(CASES[name].model(), bg.DensityModel) for name in GRID_CASES)
    assert all(isinstance(CASES[name].model(), PresenceModel) for name in ARRAY_CASES)


@pytest.mark.parametrize("name", GRID_CASES)
def test_pdf_equals_rasterise(name):
    case = CASES[name]
    model, grid = case.model(), case.grid
    raster = bg.rasterise(model, grid)
    xx, yy = np.meshgrid(grid.x, grid.y)
    points = model.pdf(xx, yy)
    if case.pdf_rtol == 0.0:
        np.testing.assert_array_equal(points, raster.values)
    else:
        live = points > 1e-12 * points.max()
        np.testing.assert_allclose(raster.values[live], points[live], rtol=case.pdf_rtol, atol=0.0)


@pytest.mark.parametrize("name", GRID_CASES)
def test_threads_do_not_change_results(name):
    case = CASES[name]
    model, grid = case.model(), case.grid
    one = bg.rasterise(model, grid, threads=1)
    for threads in (2, 3):
        many = bg.rasterise(model, grid, threads=threads)
        np.testing.assert_array_equal(many.values, one.values)
        assert many.mass == one.mass


@pytest.mark.parametrize("name", GRID_CASES)
def test_float32_within_the_stated_bound(name):
    """float32 against float64 where the density exceeds 1e-6 of its peak, within the bound the
    model class states (``float32_rtol``)."""
    case = CASES[name]
    model, grid = case.model(), case.grid
    r64 = bg.rasterise(model, grid).values
    r32 = bg.rasterise(model, grid, dtype=np.float32).values
    assert r32.dtype == np.float32
    live = r64 >= 1e-6 * r64.max()
    worst = float(np.max(np.abs(r32[live] / r64[live] - 1.0)))
    assert worst < type(model).float32_rtol, worst


#: False-alarm rate of each chi-square test (fixed seeds: deterministic outcome).
ALPHA = 1e-3
N_SAMPLES = 200_000
#: Sub-cells per bin side: the bins' probabilities by the midpoint rule on cells a tenth of the
#: grid step (at most a few 1e-4 relative for the features above, far below the 1 / sqrt(count)
#: >= 2e-3 statistical error of the fullest bins).
SUB = 10


@pytest.mark.parametrize("name", GRID_CASES)
def test_density_matches_its_own_samples(name):
    """Pearson's chi-square of the model's samples binned on its grid against the kernel's bin
    probabilities (normalised over the grid, which holds the mass), bins expecting >= 5."""
    case = CASES[name]
    model = case.model()
    fine = bg.Grid.from_bounds(**case.bounds, step=case.step / SUB)
    values = bg.rasterise(model, fine).values
    ny, nx = values.shape[0] // SUB, values.shape[1] // SUB
    probs = values[: ny * SUB, : nx * SUB].reshape(ny, SUB, nx, SUB).sum(axis=(1, 3))
    probs = probs / probs.sum()
    pts = model.sample(N_SAMPLES, np.random.default_rng(20261122))
    x0, y0 = fine.origin
    counts, _, _ = np.histogram2d(pts[:, 1], pts[:, 0], bins=(ny, nx),
                                  range=((y0, y0 + ny * case.step * 1.0), (x0, x0 + nx * case.step)))
    assert counts.sum() > (1.0 - 1e-3) * N_SAMPLES  # the grid holds the samples too
    expected = probs * counts.sum()
    assert_counts_follow(counts, expected)


@pytest.mark.parametrize("name", GRID_CASES)
def test_polar_lattice_cells_sum_to_the_grid_mass(name):
    """The lattice's Gauss-Legendre cells and the grid's midpoint rule integrate the same density
    over regions that both hold its mass (the coarse grid's midpoint rule errs by up to ~1e-4
    at these steps; the cells by 1e-9)."""
    case = CASES[name]
    model = case.model()
    polar = bg.rasterise(model, bg.PolarLattice(**case.lattice))
    assert polar.probability.min() >= 0.0
    fine = bg.rasterise(model, bg.Grid.from_bounds(**case.bounds, step=case.step / 4))
    assert abs(polar.mass - fine.mass) < 1e-4 * fine.mass, (polar.mass, fine.mass)


@pytest.mark.parametrize("name", GRID_CASES)
def test_radial_moments_along_rays(name):
    """E[r | theta] lies inside the lattice's ranges, SD > 0 and the ray mass > 0 at the
    bearing of the lattice's centre (through the protocol's radial_extent and ray_values)."""
    case = CASES[name]
    model = case.model()
    pose = None if case.pose is None else Pose(**case.pose)
    lattice = bg.PolarLattice(**case.lattice)
    bearing = 0.5 * sum(lattice.bearings) if lattice.bearings[1] - lattice.bearings[0] < math.pi else 0.0
    moments = bg.radial_moments(model, [bearing], pose=pose)
    assert lattice.ranges[0] < moments.mean[0] < lattice.ranges[1]
    assert moments.sd[0] > 0.0 and moments.mass[0] > 0.0


# --- the array kinds: presence laws on an array's angular cells --------------------------------

#: SciPy's multivariate normal (an eigendecomposition) against the law's Cholesky whitening of
#: the same well-conditioned covariances: both within a few ulp of the density; 1e-12 leaves room
#: for exp's amplification of the quadratic form's rounding (|q| < 60 at these points).
ORACLE_RTOL = 1e-12
#: A cell's relative error in float64 is below 1e-6 wherever it holds 1e-9 of the mass (the
#: quadrature's stated bound, docs), so sums of cells agree with an independent p(S) to 1e-6.
CELL_SUM_RTOL = 1e-6


def _closed_form(case: ArrayCase, points: np.ndarray, axes: int) -> np.ndarray:
    """The law's density on its first ``axes`` coordinates: SciPy's normals summed by weight, or
    1 / |S| inside the box."""
    params = case.params
    if case.kind == "uniform":
        box = bg.Region(**params["region"]).bounds[:axes]
        inside = np.all((points >= box[:, 0]) & (points <= box[:, 1]), axis=1)
        return np.where(inside, 1.0 / np.prod(box[:, 1] - box[:, 0]), 0.0)
    means = np.asarray(params["means"], dtype=float)
    covs = np.asarray(params["covs"], dtype=float).reshape(len(params["weights"]), means.shape[1], means.shape[1])
    return sum(w * stats.multivariate_normal(m[:axes], c[:axes, :axes]).pdf(points).reshape(-1)
               for w, m, c in zip(params["weights"], means, covs))


@pytest.mark.parametrize("name", ARRAY_CASES)
def test_array_pdf_matches_its_closed_form(name):
    """``pdf`` in the protocol's form (coordinates, broadcast) against the closed form, the
    convenience form ``pdf(points)`` bit for bit the same, and a 3-D law's ``pdf(x, y)`` its
    (x, y) marginal."""
    case = CASES[name]
    model = case.model()
    d = model.dim
    rng = np.random.default_rng(20261127)
    box = case.region.bounds
    shapes = [(6, 1), (1, 5), (6, 5)][:d] if d > 1 else [(6, 5)]
    coords = [rng.uniform(box[k, 0] - 1.0, box[k, 1] + 1.0, size=shape) for k, shape in enumerate(shapes)]
    values = model.pdf(*coords)
    assert values.shape == (6, 5)
    points = np.stack(np.broadcast_arrays(*coords), axis=-1).reshape(-1, d)
    np.testing.assert_array_equal(model.pdf(points), values.ravel())
    np.testing.assert_allclose(values.ravel(), _closed_form(case, points, d), rtol=ORACLE_RTOL, atol=0.0)
    if d == 3:
        np.testing.assert_allclose(model.pdf(*coords[:2]).ravel(), _closed_form(case, points[:, :2], 2),
                                   rtol=ORACLE_RTOL, atol=0.0)


@pytest.mark.parametrize("name", ARRAY_CASES)
def test_array_cells_equal_rasterise(name):
    """``rasterise`` on an AngularLattice is the law's own cell plan, bit for bit."""
    case = CASES[name]
    model, lattice, region = case.model(), case.angular, case.region
    cells = bg.rasterise(model, lattice, region=region)
    assert isinstance(cells, bg.CellMap) and cells.prob.shape == lattice.shape
    np.testing.assert_array_equal(cells.prob, model.cell_plan(lattice, region).run(WarpContext())[0].prob)
    np.testing.assert_array_equal(cells.prob, bg.cell_probabilities(model, lattice, region).prob)
    assert cells.prob.min() >= 0.0


@pytest.mark.parametrize("name", ARRAY_CASES)
def test_array_threads_do_not_change_results(name):
    case = CASES[name]
    model, lattice, region = case.model(), case.angular, case.region
    one = bg.rasterise(model, lattice, region=region, threads=1)
    for threads in (2, 3):
        np.testing.assert_array_equal(bg.rasterise(model, lattice, region=region, threads=threads).prob, one.prob)


@pytest.mark.parametrize("name", ARRAY_CASES)
def test_array_float32_within_the_stated_bound(name):
    """float32 cells against float64 where a cell holds 1e-9 of the mass, within ``float32_rtol``."""
    case = CASES[name]
    model, lattice, region = case.model(), case.angular, case.region
    r64 = bg.rasterise(model, lattice, region=region).prob
    r32 = bg.rasterise(model, lattice, region=region, dtype=np.float32).prob
    live = r64 >= 1e-9
    worst = float(np.max(np.abs(r32[live] / r64[live] - 1.0)))
    assert worst <= type(model).float32_rtol, worst


def _line_counts(points: np.ndarray, lattice) -> np.ndarray:
    """Samples per line cell: cell k lies between x = -h cot(phi) of its azimuth edges."""
    x = np.clip(lattice.line_edges(), -1e9, 1e9)  # the end cells reach to infinity
    order = np.argsort(x)
    counts = np.histogram(points[:, 0], bins=x[order])[0]
    out = np.zeros(lattice.shape[0])
    np.add.at(out, np.minimum(order[:-1], order[1:]), counts)
    return out


@pytest.mark.parametrize("name", ARRAY_CASES)
def test_array_cells_match_their_own_samples(name):
    """Pearson's chi-square of the law's samples in the room, binned by the direction the array
    sees them in, against p(C | S) times their number (bins expecting >= 5, pooled below)."""
    case = CASES[name]
    model, lattice, region = case.model(), case.angular, case.region
    cells = bg.rasterise(model, lattice, region=region).prob
    pts = model.sample(N_SAMPLES, np.random.default_rng(20261128))
    pts = pts[region.contains(pts)]
    if lattice.geometry == "line":
        counts = _line_counts(pts, lattice)
    else:
        depths = lattice.depths if lattice.geometry == "frustum" else (lattice.h, lattice.h)
        counts = bin_samples(pts, lattice.azimuth_edges, lattice.elevation_edges, depths)
    expected = (cells * len(pts)).ravel()
    counts = counts.ravel()
    assert_counts_follow(counts, expected)


@pytest.mark.parametrize("name", ARRAY_CASES)
def test_array_cells_sum_to_the_seen_part_of_the_room(name):
    """The cells cover the room's part the lattice sees (the whole line or plane; the slab
    between the frustum's depths), so they sum to its probability over the room's, each by the
    law's own ``region_probability`` (rectangle probabilities, not the cells' quadrature)."""
    case = CASES[name]
    model, lattice, region = case.model(), case.angular, case.region
    total = float(bg.rasterise(model, lattice, region=region).prob.sum())
    want = 1.0
    if lattice.geometry == "frustum":
        d0, d1 = lattice.depths
        (x, y, z) = region.bounds
        seen = bg.Region(x=tuple(x), y=tuple(y), z=(max(z[0], -d1), min(z[1], -d0)))
        want = model.region_probability(seen) / model.region_probability(region)
    assert total == pytest.approx(want, rel=CELL_SUM_RTOL, abs=0.0)


@pytest.mark.parametrize("name", list(CASES))
def test_every_kind_has_one_cell_plan_for_every_domain(name):
    """One protocol method gives a model's cells on any domain (``cell_plan``): a plan or None
    (the engine's rule) where the kind has cells, one line naming the model where it has none."""
    case = CASES[name]
    model = case.model()
    grid = CASES["cat"].grid
    angular = CASES["mixture-plane"].angular
    if case.domain == "grid":
        for domain in (grid, bg.PolarLattice(**case.lattice)):
            plan = model.cell_plan(domain)
            assert plan is None or isinstance(plan, CellPlan)
        with pytest.raises(bg.BananagridError, match=rf"^{type(model).__name__}: .*no cells of an array's directions"):
            model.cell_plan(angular)
    else:
        plan = model.cell_plan(case.angular, case.region)
        assert isinstance(plan, CellPlan) and plan.seconds is None
        cells, _ = plan.run(WarpContext())
        np.testing.assert_array_equal(cells.prob, bg.cell_probabilities(model, case.angular, case.region).prob)
        with pytest.raises(bg.BananagridError, match=rf"^{type(model).__name__}: a presence law's cells are those"):
            model.cell_plan(grid)


def test_each_domain_refuses_the_other_kind_in_one_line():
    """A planar density has no cells of an array's directions; a presence law is no planar kernel
    model; a region conditions only an angular lattice's cells."""
    cat, mixture = CASES["cat"].model(), CASES["mixture-plane"].model()
    with pytest.raises(bg.BananagridError, match=r"^CAT: a density in the world plane has no cells of an array's "):
        bg.rasterise(cat, CASES["mixture-plane"].angular)
    with pytest.raises(bg.BananagridError, match=r"^GaussianMixture: a presence law's cells are those of an Angular"):
        bg.rasterise(mixture, CASES["cat"].grid)
    with pytest.raises(bg.BananagridError, match=r"^region = Region.*: only an AngularLattice's cells"):
        bg.rasterise(cat, CASES["cat"].grid, region=bg.Region(**ROOM))


BAD = [(name, param, value, message) for name, case in CASES.items() for param, value, message in case.bad]


@pytest.mark.parametrize("name, param, value, message", BAD, ids=[f"{n}-{p}" for n, p, _, _ in BAD])
def test_bad_parameter_is_named(name, param, value, message):
    with pytest.raises(bg.BananagridError, match=message):
        CASES[name].model(**{param: value})


# --- the model of the tests: scenes and recordings too --------------------------------------

SCENE = """
[scene]
name = "isotropic"

[grid]
x = [-700.0, 1300.0]
y = [-1200.0, 800.0]
step = 40.0

[layers.normal]
model = "isotropic"
mean = [300.0, -200.0]
sigma = 150.0
"""


def test_a_model_of_the_tests_gets_a_scene_layer_and_a_recording(tmp_path):
    kinds = bg.MODEL_KINDS.with_kinds(ISOTROPIC)
    scene = parse_scene(SCENE, source="isotropic.toml", kinds=kinds)
    (layer,) = scene.layers
    assert layer.model() == IsotropicNormal(mean=(300.0, -200.0), sigma=150.0)
    rows = run_scene(scene, tmp_path)
    assert rows[0]["mass"] == pytest.approx(1.0, abs=1e-6)  # +-6.7 sigma: 2e-10 outside
    info = inspect_recording(tmp_path / "isotropic.rrd")
    assert {"/layers/normal/density", "/layers/normal/contours/lines"} <= set(info["entities"])
    with pytest.raises(bg.BananagridError, match=r'isotropic.toml: layers.normal.sigma = -1.0: must be > 0'):
        parse_scene(SCENE.replace("sigma = 150.0", "sigma = -1.0"), source="isotropic.toml", kinds=kinds)
    with pytest.raises(bg.BananagridError, match=r'layers.normal.model = "isotropic": must be one of "cat"'):
        parse_scene(SCENE, source="isotropic.toml")  # the default registry does not know it


def test_a_model_of_the_tests_matches_its_closed_form():
    """The test model's kernels are right (so the checks above test the engine, not it)."""
    model = IsotropicNormal(mean=(300.0, -200.0), sigma=150.0)
    x = np.array([300.0, 450.0, 0.0])
    y = np.array([-200.0, -200.0, 100.0])
    want = stats.multivariate_normal([300.0, -200.0], 150.0**2).pdf(np.column_stack((x, y)))
    np.testing.assert_allclose(model.pdf(x, y), want, rtol=1e-14)
