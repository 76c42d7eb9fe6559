"""A griffe extension for the API reference: docstrings as Python shows them, in Markdown.

griffe reads the source without importing it, but a ``@modelclass`` model's "Parameters"
section is written when the class is made, from its parameters' declarations
(``bananagrid.models.params``). For those classes alone this extension imports the model's
module (no Warp kernel is built or launched: importing declares them) and takes the docstring
that ``help()`` shows, and its constructor's signature (a dataclass made by ``modelclass``, which
griffe's dataclass support does not know), so the reference and the runtime cannot differ.

The docstrings cross-reference in Sphinx's roles (``:class:`Grid```, ``:meth:`~Raster.plot```);
Markdown has none, so each becomes the name in code (``Grid``, ``plot``).
"""

from __future__ import annotations

import importlib
import inspect
import re

import griffe

#: A Sphinx role: ``:class:`name```, ``:meth:`~a.b```, ``:func:`text <target>```.
ROLE = re.compile(r":(?:py:)?(?:class|meth|func|mod|attr|data|exc|obj|const):`(~?)([^`<]*?)(?:\s*<[^`>]*>)?`")


def plain_roles(text: str) -> str:
    """``text`` with each Sphinx role replaced by its name in code (``~`` keeps the last part)."""
    return ROLE.sub(lambda m: f"``{m.group(2).rsplit('.', 1)[-1] if m.group(1) else m.group(2)}``", text)


class ModelclassDocstrings(griffe.Extension):
    """A ``@modelclass`` class's generated docstring and signature; Sphinx roles as code."""

    def on_instance(self, *, obj: griffe.Object, **kwargs) -> None:
        if obj.docstring is not None:
            obj.docstring.value = plain_roles(obj.docstring.value)

    def on_class_instance(self, *, cls: griffe.Class, **kwargs) -> None:
        if not any(str(d.value).split("(")[0].endswith("modelclass") for d in cls.decorators):
            return
        runtime = getattr(importlib.import_module(cls.module.path), cls.name)
        text = plain_roles(inspect.cleandoc(runtime.__doc__ or ""))
        if cls.docstring is None:
            cls.docstring = griffe.Docstring(text, parent=cls)
        else:
            cls.docstring.value = text
        parameters = [griffe.Parameter("self", kind=griffe.ParameterKind.positional_or_keyword)]
        for parameter in inspect.signature(runtime).parameters.values():
            parameters.append(griffe.Parameter(
                parameter.name, kind=griffe.ParameterKind(parameter.kind.description),
                annotation=_annotation(parameter.annotation),
                default=None if parameter.default is inspect.Parameter.empty else repr(parameter.default)))
        init = griffe.Function("__init__", parent=cls, returns="None", parameters=griffe.Parameters(*parameters))
        cls.set_member("__init__", init)


def _annotation(annotation) -> str | None:
    """The annotation as the source spells it (``from __future__ import annotations``: a string)."""
    if annotation is inspect.Parameter.empty:
        return None
    return annotation if isinstance(annotation, str) else getattr(annotation, "__name__", repr(annotation))
