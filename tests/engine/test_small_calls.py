"""What a small call skips keeps every guarantee: framing boxes at once gives ``from_bounds``'s
grids or its errors, the kept thread pool runs every band once and raises a band's error, a
class remembered as a model still lets nothing else through, an estimate too small to read the
system's memory for is still refused against a limit given, and a binding kept in a model is
the one it would make (and does not travel with a pickled copy)."""

import math
import pickle
import threading

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import bananagrid as bg
from bananagrid.engine import memory
from bananagrid.engine.batch import grids_in
from bananagrid.engine.grid_kernel import GridExtent
from bananagrid.engine.points import check_model
from bananagrid.engine.warp_runtime import WarpContext, run_bands

#: Magnitudes over float64's whole range, subnormal spans included: boxes whose steps round,
#: overflow or fall below the coordinates' resolution (from_bounds's and Grid's refusals).
EXPONENTS = st.floats(-320.0, 307.0)


@settings(max_examples=300, deadline=None, derandomize=True, database=None)
@given(centre=EXPONENTS, width=EXPONENTS, sign=st.sampled_from([-1.0, 1.0]), aspect=st.floats(-1.0, 2.0),
       ny=st.integers(1, 200), nx=st.integers(1, 200), flip=st.booleans())
def test_grids_in_are_from_bounds_grids_or_its_errors(centre, width, sign, aspect, ny, nx, flip):
    """Each box's grid equals ``Grid.from_bounds`` of it field for field, or both refuse with the
    same message (an empty or reversed box, a step below the coordinates' resolution)."""
    c, w = sign * 10.0**centre, 10.0**width
    box = (c, c + w, -c, -c + w * 10.0**aspect)
    if flip:
        box = (box[1], box[0], box[2], box[3])
    x0, x1, y0, y1 = box
    try:
        expected = bg.Grid.from_bounds(x=(x0, x1), y=(y0, y1), dx=(x1 - x0) / nx, dy=(y1 - y0) / ny)
    except bg.BananagridError as exc:
        with pytest.raises(bg.BananagridError) as raised:
            grids_in(np.array([box]), (ny, nx))
        assert str(raised.value) == str(exc)
        return
    (got,) = grids_in(np.array([box]), (ny, nx))
    assert got == expected and got.shape == (ny, nx)
    assert all(type(v) is float for v in (*got.origin, got.dx, got.dy))


def test_run_bands_runs_every_band_once_on_a_kept_pool():
    """Every band once, from the calling thread and the pool's; the pool's threads are the same
    in the next call (none started per call)."""
    seen, names = [], set()
    lock = threading.Lock()

    def band(a, b):
        with lock:
            seen.append((a, b))
            names.add(threading.current_thread().name)

    bands = [(k, k + 1) for k in range(64)]
    before = threading.active_count()
    for _ in range(5):
        run_bands(band, bands, 3)
    assert sorted(seen) == sorted(bands * 5)
    # at most the two helpers of a 3-thread call, named for their pool, alive between calls
    assert {n for n in names if n != threading.current_thread().name} <= {"bananagrid-bands2_0", "bananagrid-bands2_1"}
    assert threading.active_count() <= before + 2
    run_bands(band, bands, 3)
    assert threading.active_count() <= before + 2


def test_run_bands_raises_a_bands_error_after_every_band():
    done = []

    def band(a, b):
        if a == 5:
            raise ValueError("band 5")
        done.append(a)

    with pytest.raises(ValueError, match="band 5"):
        run_bands(band, [(k, k + 1) for k in range(16)], 2)
    assert sorted(done) == [k for k in range(16) if k != 5]


def test_run_bands_inside_a_band_and_from_several_threads():
    """Calls nested in a band and calls from several threads at once all finish (the caller
    waits for its bands, never for helpers queued behind other calls)."""
    total = []
    lock = threading.Lock()

    def inner(a, b):
        with lock:
            total.append(1)

    def outer(a, b):
        run_bands(inner, [(k, k + 1) for k in range(8)], 2)

    callers = [threading.Thread(target=run_bands, args=(outer, [(k, k + 1) for k in range(6)], 2)) for _ in range(4)]
    for t in callers:
        t.start()
    for t in callers:
        t.join(timeout=60)
    assert not any(t.is_alive() for t in callers)
    assert len(total) == 4 * 6 * 8


class _Impostor:
    """Has ``pdf`` and ``bind`` but not the rest of the protocol."""

    def pdf(self, x, y):
        return x

    def bind(self, ctx, extent, grid=False):
        return None


def test_a_remembered_model_class_lets_nothing_else_through():
    model = bg.PolarBanana(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54)
    for _ in range(2):  # after a model's class is remembered, others are still checked each time
        assert check_model(model) is model
        for other in (_Impostor(), object(), "polar", None):
            with pytest.raises(bg.BananagridError, match=rf"^model = {type(other).__name__}: not a bananagrid model$"):
                bg.rasterise(other, bg.Grid.from_bounds(x=(0.0, 1.0), y=(0.0, 1.0), step=0.5))


def test_small_estimates_do_not_read_the_system_but_a_limit_still_refuses(monkeypatch):
    reads = []

    def available():
        reads.append(1)
        return 1000  # a system with 1 kB: every estimate above it refused once it is read

    monkeypatch.setattr(memory, "available_bytes", available)
    assert memory.check_memory(1, memory.UNCHECKED_BYTES, "small") == memory.UNCHECKED_BYTES
    assert not reads
    with pytest.raises(bg.BananagridError, match=r"^big needs about 4\.19 MB .* more than the 1 kB available"):
        memory.check_memory(1, memory.UNCHECKED_BYTES + 1, "big")
    assert reads == [1]
    with pytest.raises(bg.BananagridError, match=r"^limited needs about 2 kB .* more than the 1 kB allowed"):
        memory.check_memory(2, 1000.0, "limited", limit=1000.0)


@pytest.mark.parametrize("model", [
    bg.PolarBanana(v0=280.0, t=10.0, sigma_a=5 / 3, sigma_omega=math.pi / 54, sigma_heading=0.05),
    bg.BearingFix(sensors=[(0.0, 0.0), (20000.0, 0.0)], bearings=[0.2641, -0.3909], sigmas=[0.01, 0.02]),
], ids=["polar", "bearing"])
def test_a_kept_binding_is_the_one_made_and_stays_in_its_process(model):
    """The binding is made once per (dtype, device) and reused; a pickled copy carries none,
    makes its own and computes the same bits."""
    rng = np.random.default_rng(3)
    pts = model.sample(200, rng)
    f64, f32 = WarpContext(np.float64), WarpContext(np.float32)
    first = model.bind(f64, None)
    assert model.bind(f64, None) is first and model.bind(f32, None) is not first
    values = model.pdf(pts[:, 0], pts[:, 1])
    copy = pickle.loads(pickle.dumps(model))
    assert "_bindings" not in copy.__dict__
    assert np.array_equal(copy.pdf(pts[:, 0], pts[:, 1]), values)
    fresh = type(model)(**{k: getattr(model, k) for k in model.__dataclass_fields__})
    assert np.array_equal(fresh.pdf(pts[:, 0], pts[:, 1]), values)


@settings(max_examples=200, deadline=None, derandomize=True, database=None)
@given(ox=st.floats(-1e12, 1e12), oy=st.floats(-1e12, 1e12), dx=st.floats(1e-3, 1e6), dy=st.floats(1e-3, 1e6),
       nx=st.integers(1, 5000), ny=st.integers(1, 5000), px=st.floats(-1e12, 1e12), py=st.floats(-1e12, 1e12))
def test_a_grids_extent_is_that_of_all_its_centres(ox, oy, dx, dy, nx, ny, px, py):
    """GridExtent's nearest and farthest distances, from the first and last centres alone,
    equal those of every centre's coordinates (Grid.x and Grid.y computed in full)."""
    try:
        grid = bg.Grid(origin=(ox, oy), dx=dx, dy=dy, nx=nx, ny=ny)
    except bg.BananagridError:
        return  # cells below the coordinates' resolution: no grid
    xs, ys = grid.x - px, grid.y - py
    near_x = 0.0 if xs[0] <= 0.0 <= xs[-1] else float(np.abs(xs).min())
    near_y = 0.0 if ys[0] <= 0.0 <= ys[-1] else float(np.abs(ys).min())
    far = math.hypot(float(np.abs(xs).max()), float(np.abs(ys).max()))
    assert GridExtent(grid).radii((px, py)) == (math.hypot(near_x, near_y), far)
