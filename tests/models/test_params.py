"""Parameters declared once: every registered model's fields carry their declaration
(:func:`bananagrid.models.params.param`), and its scene keys, required keys, docstring
Parameters section and ``parameters()`` all derive from them."""

import re
from dataclasses import fields

import numpy as np
import pytest

import bananagrid as bg
from bananagrid.models.params import METADATA, declared, modelclass, param, parameters_section, scene_keys
from bananagrid.protocol import SceneSchema
from bananagrid.validate import non_negative, positive

from cases import FIG1

#: Scene parameters (SI) of one model of every registered kind.
PARAMS = {
    "cat": {**FIG1, "origin": (10.0, -20.0), "heading": 0.3},
    "polar": {**FIG1, "variant": "rough"},
    "bearing_fix": dict(sensors=[(0.0, 0.0), (20000.0, 0.0)], bearings=[0.2641, -0.3909], sigmas=[0.01, 0.02]),
    "butterly": dict(mean=(1.0, 2.0), cov=[[4e4, 5e3], [5e3, 2.5e4]], speeds=[1.0, 2.0], weights=[0.4, 0.6], t=600.0),
    "mixture": dict(weights=[0.7, 0.3], means=[[-1.8, 1.5], [1.2, -1.8]], covs=[np.diag([0.0625, 0.0625]),
                                                                           [[0.0225, 0.0135], [0.0135, 0.09]]]),
    "uniform": dict(region=bg.Region(x=(-3.0, 3.0), y=(-2.5, 2.5))),
}
KINDS = list(bg.MODEL_KINDS)


def test_every_registered_kind_has_parameters_here():
    assert set(bg.MODEL_KINDS) <= set(PARAMS)


@pytest.mark.parametrize("kind", KINDS)
def test_every_field_is_declared_once_and_its_scene_keys_derive_from_it(kind):
    cls = bg.MODEL_KINDS[kind].cls
    public = [f.name for f in fields(cls) if f.init and not f.name.startswith("_")]
    assert [f.name for f, _ in declared(cls)] == public  # every parameter is declared
    assert cls.scene.keys == scene_keys(cls)  # the scene's keys are the declarations'
    names = [key.name for key in cls.scene.keys]
    assert len(names) == len(set(names))
    for f, spec in declared(cls):  # each field is set by a key of its own name, or by the keys it names,
        # or is declared as set by none (scene=(): a uniform law's region is the scene's [room])
        assert f.name in names or spec.scene or (spec.scene == () and not spec.also), f.name


@pytest.mark.parametrize("kind", KINDS)
def test_the_docstring_parameters_section_is_generated_from_the_declarations(kind):
    cls = bg.MODEL_KINDS[kind].cls
    doc = cls.__doc__
    assert parameters_section(cls) in doc
    assert doc.count("Parameters\n----------") == 1
    section = doc.split("Parameters\n----------\n")[1].split("\n\n")[0]
    entries = re.findall(r"^(\w+) : ", section, flags=re.MULTILINE)
    assert entries == [f.name for f, _ in declared(cls)]
    for f, spec in declared(cls):
        if spec.unit:
            assert f"Unit: {spec.unit}." in section.split(f"{f.name} : ")[1].split("\n\n")[0]


@pytest.mark.parametrize("kind", KINDS)
def test_parameters_cover_every_declared_field(kind):
    model = bg.MODEL_KINDS[kind].build(PARAMS[kind])
    plain = model.parameters()
    assert plain["model"] == type(model).__name__
    for f, spec in declared(type(model)):
        own = spec.plain(model, getattr(model, f.name)) if spec.plain is not None else {f.name: getattr(model, f.name)}
        assert own.items() <= plain.items()
    # plain data: numbers, strings, and lists and mappings of them, as recordings and JSON take them
    def plain_data(value):
        if isinstance(value, (list, dict)):
            return all(plain_data(v) for v in (value.values() if isinstance(value, dict) else value))
        return isinstance(value, (int, float, str)) and not isinstance(value, np.generic)

    for key, value in plain.items():
        assert plain_data(value), (key, value)


def test_required_keys_are_the_fields_without_a_default():
    assert bg.CAT.scene.required == ("v0", "sigma_a", "sigma_omega")  # t: timed, scene.times may give it
    assert bg.BearingFix.scene.required == ("sensors", "bearings", "sigmas")
    assert bg.Butterly.scene.required == ("mean",)  # cov and the speeds: one of several ways, the missing rule's


def test_a_model_class_of_a_few_lines():
    @modelclass
    class Drift(bg.Model):
        """A drifting point."""

        speed: float = param(unit="m/s", check=positive, doc="How fast it drifts.")
        t: float = param(unit="s", check=non_negative, doc="Elapsed time.")
        variant: str = param("slow", type="choice", choices=("slow", "fast"), py="str", domain="slow or fast",
                             doc="Which drift.")

        kind = "drift"
        scene = SceneSchema(timed=True, summary="a drifting point")

        def __post_init__(self):  # a rule between parameters, after the declared checks
            if self.variant == "fast" and self.speed < 1.0:
                raise bg.BananagridError(f"speed = {self.speed!r}: a fast drift is at least 1 m/s")

    @modelclass
    class Drifts(Drift):
        """Two drifting points."""

        gap: float = param(1.0, unit="m", check=positive, doc="Their distance.")

        kind = "drifts"
        scene = SceneSchema(timed=True, summary="two drifting points")

    keys = {key.name: key for key in Drift.scene.keys}
    assert list(keys) == ["speed", "t", "variant"]
    assert keys["speed"].unit == "m/s" and keys["speed"].default == "required"
    assert keys["variant"].default == '`"slow"`' and keys["variant"].choices == ("slow", "fast")
    assert Drift.scene.required == ("speed",)
    assert Drift.scene.build({"speed": 2.0, "t": 1.0}) == Drift(speed=2.0, t=1.0)
    assert Drift(speed=2.0, t=1.0).parameters() == {"model": "Drift", "speed": 2.0, "t": 1.0, "variant": "slow"}
    assert "speed : float\n    How fast it drifts. Unit: m/s. Allowed: finite, > 0." in Drift.__doc__
    assert "variant : str, default \"slow\"" in Drift.__doc__
    with pytest.raises(AttributeError):  # frozen
        Drift(speed=2.0, t=1.0).speed = 3.0
    assert METADATA in fields(Drift)[0].metadata
    # the declared checks run on construction, in field order, then the class's own rule
    assert keys["speed"].allowed == "finite, > 0" and keys["t"].allowed == "finite, >= 0"
    assert Drift(speed=2, t=1).speed == 2.0 and type(Drift(speed=2, t=1).speed) is float
    with pytest.raises(bg.BananagridError, match=r"^speed = -1.0: must be > 0$"):
        Drift(speed=-1.0, t=-1.0)
    with pytest.raises(bg.BananagridError, match=r"^speed = 0.5: a fast drift is at least 1 m/s$"):
        Drift(speed=0.5, t=1.0, variant="fast")
    # a subclass keeps its parent's checks and rule, and adds its own
    assert [key.name for key in Drifts.scene.keys] == ["speed", "t", "variant", "gap"]
    with pytest.raises(bg.BananagridError, match=r"^gap = 0.0: must be > 0$"):
        Drifts(speed=2.0, t=1.0, gap=0.0)
    with pytest.raises(bg.BananagridError, match=r"a fast drift"):
        Drifts(speed=0.5, t=1.0, variant="fast")


def test_a_hand_written_parameters_section_is_refused():
    with pytest.raises(TypeError, match="must not have its own Parameters section"):
        @modelclass
        class Twice(bg.Model):
            """Twice.

            Parameters
            ----------
            a : float
            """

            a: float = param(doc="A.")


def test_the_docs_keep_their_derived_defaults():
    """Defaults as a scene writes them: 8.0 as `8`, strings in quotes."""
    keys = {key.name: key for key in bg.CAT.scene.keys}
    assert keys["k_sigma"].default == "`8`" and keys["sigma_heading"].default == "`0`"
    assert {key.name: key for key in bg.PolarBanana.scene.keys}["variant"].default == '`"improved"`'
    assert np.isfinite(bg.CAT.scene.build(PARAMS["cat"]).k_sigma)


def test_bench_times_every_registered_kind():
    """The bench's grid rows are parameter sets of registered kinds, built through the registry:
    a kind added to the registry must get one (and nothing else names the kinds)."""
    from bananagrid.bench.runner import GRID_ROWS, grid_model

    assert {kind for kind, _ in GRID_ROWS.values()} == set(bg.MODEL_KINDS.on("grid"))  # array kinds have no grid rows
    for name, (kind, _) in GRID_ROWS.items():
        assert isinstance(grid_model(name), bg.MODEL_KINDS[kind].cls)
