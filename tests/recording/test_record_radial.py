"""The conditional radial curves (Figures 2-5 and 8) in a scene's recording read back equal to
what :func:`bananagrid.record_radial.radial_curves` computes, and the viewer gets their tabs."""

import math

import numpy as np
import pytest
from rerun.chunk import RrdReader

from bananagrid.recording.radial import radial_curves, radial_groups
from bananagrid.scenes.run import run_scene
from bananagrid.scenes.load import parse_scene

from cases import small_scene

SCENE = small_scene("radial", """\
[layers.exact]
model = "cat"
sigma_a = 0.2          # sigma_a t / v0 = 0.1: a banana that neither stops nor folds
sigma_heading_deg = 5.0

[layers.approx]
model = "polar"

[radial]
layers = ["exact"]
density_bearings_deg = [10.0]
moments_max_deg = 20.0
moments_step_deg = 5.0
""")


def bar_charts(path, root):
    """{entity below root: (abscissa, values)} of every BarChart in the recording."""
    out = {}
    for chunk in RrdReader(path).stream():
        entity = str(chunk.entity_path)
        if not entity.startswith(root):
            continue
        batch = chunk.to_record_batch()
        if "BarChart:values" not in batch.schema.names:
            continue
        cell = lambda name: np.asarray(batch.column(name)[0].values[0].as_py()["buffer"], dtype=float)
        out[entity[len(root):]] = (cell("BarChart:abscissa"), cell("BarChart:values"))
    return out


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    scene = parse_scene(SCENE)
    out = tmp_path_factory.mktemp("radial")
    run_scene(scene, out)
    return scene, out / "radial.rrd"


def test_curves_read_back(recorded):
    scene, path = recorded
    got = bar_charts(path, "/radial/exact/")
    want = radial_curves(scene.layers[0].model(), density_bearings=[math.radians(10.0)],
                         moments_max=math.radians(20.0), moments_step=math.radians(5.0))["curves"]
    assert set(got) == set(want)
    # density curves: exact, moment-matched normal, closed forms of both orders (heading noise)
    assert {"density/10deg/exact", "density/10deg/normal", "density/10deg/closed_form",
            "density/10deg/closed_form_order4"} <= set(got)
    for name, (abscissa, values) in want.items():
        assert np.array_equal(got[name][0], abscissa) and np.array_equal(got[name][1], values), name
    # bearings 0, 5, ..., 20 deg for the moment curves
    assert np.array_equal(got["mean/exact"][0], [0.0, 5.0, 10.0, 15.0, 20.0])


def test_only_the_chosen_layers_get_curves(recorded):
    _, path = recorded
    assert not bar_charts(path, "/radial/approx/")


def test_groups_name_the_viewer_tabs():
    assert radial_groups([math.radians(45.0), math.radians(72.0)], math.radians(90.0)) == [
        "density/45deg", "density/72deg", "mean", "mean_error", "sd"
    ]
