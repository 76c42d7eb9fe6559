"""Model parameters declared once: a field's type, unit, domain, scene key and documentation
live beside it, and everything else is derived from them.

A model class is a :func:`modelclass` (a frozen dataclass) whose fields are declared with
:func:`param`::

    @modelclass
    class Drift(Model):
        \"\"\"A target drifting from a normal start.\"\"\"

        mean: tuple = param(type="pair", unit="m", py="(float, float)", check=point, doc="Mean of the start.")
        t: float = param(unit="s", check=non_negative, doc="Elapsed time.")
        q: float = param(0.0, unit="m^2/s", check=non_negative, doc="Diffusion of the velocity error.")

        kind = "cv"
        scene = SceneSchema(timed=True, summary="a drifting target")

From the declarations come

* the scene keys (:attr:`SceneSchema.keys <bananagrid.protocol.SceneSchema>`, in field order;
  a field may be set by other keys as well, ``also``, or by keys of other names, ``scene``)
  and the required ones (fields without a default, but ``t`` of a timed kind and fields set
  another way too, which the schema's ``missing`` rules), and ``build`` (the class itself);
* ``parameters()``, the plain data of provenance and recordings
  (:meth:`bananagrid.models.base.Model.parameters`);
* the "Parameters" section of the class docstring, and ``docs/scenes.md``;
* the checks of the values: a parameter's ``check`` (one of :mod:`bananagrid.validate`'s,
  ``check(name, value) -> value``) runs on construction, in field order, before the class's own
  ``__post_init__`` (for the rules between parameters), and states its domain (``check.domain``).
"""

from __future__ import annotations

import dataclasses
import inspect
import re
import warnings
from collections.abc import Callable
from dataclasses import MISSING, dataclass, field, fields
from typing import Any, dataclass_transform

from ..protocol import SceneKey, SceneSchema
from ..validate import BananagridWarning, radian_doubt

__all__ = ["Param", "param", "modelclass", "declared", "scene_keys", "plain_parameters", "parameters_section", "METADATA"]

#: The key of a field's :class:`Param` in its dataclass metadata.
METADATA = "bananagrid.param"


@dataclass(frozen=True)
class Param:
    """One parameter, declared beside its field (see :func:`param` for the attributes)."""

    doc: str
    unit: str = ""
    domain: str = "finite"
    check: Callable | None = None
    type: str = "number"
    py: str = "float"
    alias: str | None = None
    choices: tuple = ()
    bearing_at: str | None = None
    default_doc: str | None = None
    scene: tuple | None = None
    also: tuple = ()
    plain: Callable | None = None


def param(default=MISSING, *, doc: str, unit: str = "", domain: str | None = None, check: Callable | None = None,
          type: str = "number",
          py: str = "float", alias: str | None = None, choices: tuple = (), bearing_at: str | None = None,
          default_doc: str | None = None, scene: tuple | None = None, also: tuple = (),
          plain: Callable | None = None, default_factory=MISSING, **kwargs) -> Any:
    """A dataclass field that declares a model parameter.

    Parameters
    ----------
    default, default_factory
        As for :func:`dataclasses.field`; none: the parameter is required.
    doc : str
        What it is, for the docstring (a sentence or two).
    unit : str
        SI unit ("" for none).
    domain : str, optional
        What is allowed, as the scene documentation states it (default: ``check.domain``, else
        "finite").
    check : callable, optional
        ``check(name, value) -> value``: refuses a value out of the domain with a
        :class:`~bananagrid.BananagridError` naming it, and gives the value as the model keeps it
        (a float, an array); run on construction (see :func:`modelclass`). None: the class's own
        ``__post_init__`` checks it.
    type : str
        The scene key's type, one of :data:`bananagrid.protocol.KEY_TYPES`.
    py : str
        Its Python type, for the docstring.
    alias, choices, bearing_at
        As for :class:`~bananagrid.protocol.SceneKey`.
    default_doc : str, optional
        The scene documentation's default (derived from ``default`` when not given).
    scene : tuple of SceneKey, optional
        The scene keys that set it when they are not its own name (a pose: ``origin`` and
        ``heading``); ``()`` for a parameter scenes do not set.
    also : tuple of SceneKey
        Further scene keys that set it another way (standard deviations for a covariance).
    plain : callable, optional
        ``plain(model, value) -> dict``: its entries in :meth:`parameters` (default
        ``{name: value}``).
    kwargs
        More :func:`dataclasses.field` arguments (``repr``, ``compare``, ...).
    """
    if domain is None:
        domain = getattr(check, "domain", "finite")
    spec = Param(doc=doc, unit=unit, domain=domain, check=check, type=type, py=py, alias=alias, choices=tuple(choices),
                 bearing_at=bearing_at, default_doc=default_doc, scene=scene, also=tuple(also), plain=plain)
    return field(default=default, default_factory=default_factory, metadata={METADATA: spec}, **kwargs)


def declared(cls) -> list[tuple[dataclasses.Field, Param]]:
    """The declared parameters of dataclass ``cls``: its init fields with their :class:`Param`."""
    return [(f, f.metadata[METADATA]) for f in fields(cls) if f.init and METADATA in f.metadata]


def _default(f: dataclasses.Field):
    """The field's default value, or MISSING."""
    if f.default is not MISSING:
        return f.default
    if f.default_factory is not MISSING:
        return f.default_factory()
    return MISSING


def _shown(value) -> str:
    """A default as a scene writes it: ``8``, ``0.5``, ``"improved"``."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e15:
        return str(int(value))
    if isinstance(value, str):
        return f'"{value}"'
    return repr(value)


def _default_doc(f: dataclasses.Field, spec: Param) -> str:
    if spec.default_doc is not None:
        return spec.default_doc
    value = _default(f)
    return "required" if value is MISSING else f"`{_shown(value)}`"


def scene_keys(cls) -> tuple[SceneKey, ...]:
    """The scene keys of ``cls``'s declared parameters, in field order."""
    keys = []
    for f, spec in declared(cls):
        if spec.scene is not None:
            keys += spec.scene
        else:
            keys.append(SceneKey(f.name, type=spec.type, unit=spec.unit, default=_default_doc(f, spec),
                                 allowed=spec.domain, alias=spec.alias, choices=spec.choices,
                                 bearing_at=spec.bearing_at))
        keys += spec.also
    return tuple(keys)


def _required(cls, timed: bool) -> tuple[str, ...]:
    """Parameters every layer gives: declared fields without a default, set by their own key
    alone (not ``t`` of a timed kind, which ``scene.times`` may give)."""
    return tuple(
        f.name for f, spec in declared(cls)
        if _default(f) is MISSING and spec.scene is None and not spec.also and not (timed and f.name == "t")
    )


def plain_parameters(model) -> dict:
    """``{"model": class name, ...}``: every init field's entries (its :class:`Param`'s
    ``plain``, else ``name: value``); private fields are left out."""
    out = {"model": type(model).__name__}
    for f in fields(model):
        if not f.init or f.name.startswith("_"):
            continue
        value = getattr(model, f.name)
        spec = f.metadata.get(METADATA)
        if spec is not None and spec.plain is not None:
            out.update(spec.plain(model, value))
        else:
            out[f.name] = value
    return out


#: A numpydoc section header: a title line underlined by dashes.
_SECTION = re.compile(r"^(\S[^\n]*)\n-+$", re.MULTILINE)


def _entry(f: dataclasses.Field, spec: Param) -> str:
    value = _default(f)
    head = f"{f.name} : {spec.py}"
    if value is not MISSING:
        head += f", default {_shown(value)}"
    unit = f" Unit: {spec.unit}." if spec.unit else ""
    keys = ""
    if spec.scene is not None and spec.scene:
        keys = " Scene keys: " + ", ".join(f"``{k.name}``" for k in spec.scene) + "."
    body = f"{spec.doc}{unit} Allowed: {spec.domain}.{keys}"
    return head + "\n" + "\n".join("    " + line for line in _wrap(body, 92))


def _wrap(text: str, width: int) -> list[str]:
    lines, line = [], ""
    for word in text.split():
        if line and len(line) + 1 + len(word) > width:
            lines.append(line)
            line = word
        else:
            line = f"{line} {word}" if line else word
    return [*lines, line] if line else lines


def parameters_section(cls) -> str:
    """The numpydoc "Parameters" section of ``cls``'s declared parameters."""
    return "Parameters\n----------\n" + "\n".join(_entry(f, spec) for f, spec in declared(cls))


def _with_section(doc: str | None, section: str) -> str:
    """``doc`` (cleaned) with ``section`` before its first numpydoc section (or at its end)."""
    text = inspect.cleandoc(doc or "")
    if _SECTION.search(text) and _SECTION.search(text).group(1) == "Parameters":
        raise TypeError("a modelclass's docstring must not have its own Parameters section: it is generated")
    found = _SECTION.search(text)
    if found is None:
        return f"{text}\n\n{section}\n"
    return f"{text[:found.start()]}{section}\n\n{text[found.start():]}"


@dataclass_transform(frozen_default=True, field_specifiers=(param, field))
def _warn_degrees(model) -> None:
    """Warn where a parameter in radians that has a degrees form in scenes (``alias="deg"``)
    looks like degrees (:func:`~bananagrid.validate.radian_doubt`: an angle beyond a full
    turn, a turn rate that turns more than one in the model's elapsed time ``t``)."""
    t = getattr(model, "t", None)
    for f, spec in declared(type(model)):
        if spec.alias != "deg":
            continue
        try:
            text = radian_doubt(f"{type(model).__name__}: {f.name}", getattr(model, f.name), spec.unit,
                                t if isinstance(t, (int, float)) else None)
        except (TypeError, ValueError):  # not numbers: the checks' business
            continue
        if text is not None:
            warnings.warn(text, BananagridWarning, stacklevel=4)  # the caller of the class


def modelclass(cls=None, /, **options):
    """A frozen dataclass of declared parameters (:func:`param`), with what derives from them:
    ``scene``'s keys, required keys and ``build`` where its :class:`SceneSchema` leaves them
    out, and the docstring's Parameters section. ``options`` go to :func:`dataclasses.dataclass`
    (``eq``, ``kw_only``). The declared checks run on construction, before the class's own
    ``__post_init__``."""

    def wrap(klass):
        own = klass.__dict__.get("__post_init__")
        if own is None:  # inherited: a declared parent's own rules, not its checks again
            inherited = getattr(klass, "__post_init__", None)
            own = getattr(inherited, "own", inherited)

        def __post_init__(self):
            for f, spec in declared(type(self)):
                if spec.check is not None:
                    object.__setattr__(self, f.name, spec.check(f.name, getattr(self, f.name)))
            if own is not None:
                own(self)
            _warn_degrees(self)

        __post_init__.__doc__ = "Run the declared parameters' checks, then the class's own rules."
        __post_init__.own = own
        klass.__post_init__ = __post_init__
        klass = dataclass(frozen=True, **options)(klass)
        schema = klass.__dict__.get("scene")
        if isinstance(schema, SceneSchema):
            changes = {}
            if not schema.keys:
                changes["keys"] = scene_keys(klass)
            if schema.required is None:
                changes["required"] = _required(klass, schema.timed)
            if schema.build is None:
                changes["build"] = lambda params: klass(**params)
            if changes:
                klass.scene = dataclasses.replace(schema, **changes)
        klass.__doc__ = _with_section(klass.__doc__, parameters_section(klass))
        return klass

    return wrap if cls is None else wrap(cls)
