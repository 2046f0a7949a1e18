"""The scene's design: one value per parameter of its design space, with controls built from the declaration.

A scene keeps its design as rows (``scene.meta_sim.design``), one per parameter of the space, each
holding its value as text exactly as a design holds it: a choice id, or a number written so it reads
back bit for bit. So a preset applies exactly and the farm renders the value the panel shows. The
controls are views on that text, made from the parameter's declaration: a roof texture parameter is a
thumbnail picker, another categorical one a menu of its choices, a continuous one a slider over its
range beside a number field. A new design space needs no change here.
"""

from __future__ import annotations

import bpy
from bpy.props import EnumProperty, FloatProperty, StringProperty

from ..meta_sim.sim.design import Categorical, DesignSpace
from . import library as libraries
from . import previews


def _parameter(row):
    """The parameter of the scene's space a row holds, or None (the space cannot be read, or the row is of
    another space)."""
    space = libraries.space_quietly(row.id_data.meta_sim)
    return space.parameter(row.name) if space is not None and row.name in space.names else None


def _choice_items(self, context):
    parameter = _parameter(self)
    return previews.choice_items(libraries.get_quietly(self.id_data.meta_sim), parameter)


def _get_choice(self) -> int:
    parameter = _parameter(self)
    if not isinstance(parameter, Categorical) or self.text not in parameter.choices:
        return 0
    return parameter.choices.index(self.text)


def _set_choice(self, value: int) -> None:
    parameter = _parameter(self)
    if isinstance(parameter, Categorical) and 0 <= value < len(parameter.choices):
        self.text = parameter.choices[value]


def _number(row, parameter) -> float:
    try:
        return min(max(float(row.text), parameter.low), parameter.high)
    except ValueError:
        return parameter.low


def _get_share(self) -> float:
    parameter = _parameter(self)
    if parameter is None or isinstance(parameter, Categorical):
        return 0.0
    return (_number(self, parameter) - parameter.low) / (parameter.high - parameter.low)


def _set_share(self, value: float) -> None:
    parameter = _parameter(self)
    if parameter is not None and not isinstance(parameter, Categorical):
        share = min(max(float(value), 0.0), 1.0)
        self.text = repr(parameter.low + share * (parameter.high - parameter.low))


def _get_number(self) -> float:
    parameter = _parameter(self)
    return 0.0 if parameter is None or isinstance(parameter, Categorical) else _number(self, parameter)


def _set_number(self, value: float) -> None:
    parameter = _parameter(self)
    if parameter is not None and not isinstance(parameter, Categorical):
        self.text = repr(min(max(float(value), parameter.low), parameter.high))


class MetaSimDesignValue(bpy.types.PropertyGroup):
    """One parameter's value (``name`` is the parameter's); ``choice``, ``share`` and ``value`` show ``text``."""

    text: StringProperty(name="Value", description="The value exactly as the design holds it")
    choice: EnumProperty(name="Choice", description="The parameter's choice", items=_choice_items,
                         get=_get_choice, set=_set_choice)
    share: FloatProperty(name="Share", description="Where the value lies in the parameter's range",
                         min=0.0, max=1.0, subtype="FACTOR", get=_get_share, set=_set_share)
    value: FloatProperty(name="Value", description="The parameter's value (kept within its range)",
                         get=_get_number, set=_set_number, precision=3)


def _fits(text: str, parameter) -> bool:
    if isinstance(parameter, Categorical):
        return text in parameter.choices
    try:
        return parameter.low <= float(text) <= parameter.high
    except ValueError:
        return False


def _text(value) -> str:
    return value if isinstance(value, str) else repr(float(value))


def fits(settings, space: DesignSpace) -> bool:
    """Whether the scene's rows are exactly the space's parameters, in order, each with a value it allows."""
    rows = list(settings.design)
    return [row.name for row in rows] == list(space.names) and all(
        _fits(row.text, p) for row, p in zip(rows, space.parameters))


def fit(settings, space: DesignSpace) -> None:
    """Make the scene's rows the space's parameters, keeping each value the space allows; a new one starts at
    the parameter's first choice or the middle of its range."""
    if fits(settings, space):
        return
    kept = {row.name: row.text for row in settings.design}
    settings.design.clear()
    for parameter in space.parameters:
        row = settings.design.add()
        row.name = parameter.name
        text = kept.get(parameter.name, "")
        if not _fits(text, parameter):
            text = (parameter.choices[0] if isinstance(parameter, Categorical)
                    else repr((parameter.low + parameter.high) / 2.0))
        row.text = text


def design(settings, space: DesignSpace) -> dict:
    """The scene's design in ``space``, validated (the rows are fitted to the space first)."""
    fit(settings, space)
    raw = {row.name: row.text if isinstance(space.parameter(row.name), Categorical) else float(row.text)
           for row in settings.design}
    return space.validate(raw)


def set_design(settings, space: DesignSpace, chosen: dict) -> None:
    """Point the rows at a design of ``space`` (validated first: nothing changes when it does not fit)."""
    chosen = space.validate(chosen)
    fit(settings, space)
    for row in settings.design:
        row.text = _text(chosen[row.name])


def texture_row(settings, kind: str):
    """The row of the space's roof texture parameter of ``kind``, or None."""
    space = libraries.space_quietly(settings)
    parameter = space.texture_parameter(kind) if space is not None else None
    return settings.design.get(parameter.name) if parameter is not None else None


def draw(layout, settings, library) -> None:
    """A control per parameter of the library's space, from its declaration."""
    space = library.space
    if not fits(settings, space):
        layout.label(text=f"Load the design space {space.name} to show its parameters", icon="INFO")
        return
    for kind in ("flat", "sloped"):
        if space.texture_parameter(kind) is None:
            layout.label(text=f"No {kind} roof textures in this space: no {kind} roofs", icon="INFO")
    column = layout.column(align=True)
    for row, parameter in zip(settings.design, space.parameters):
        label = parameter.name.replace("_", " ").capitalize()
        if isinstance(parameter, Categorical) and parameter.texture_kind:
            box = layout.box()
            box.label(text=label)
            box.template_icon_view(row, "choice", show_labels=True, scale=4.0, scale_popup=5.0)
            box.prop(row, "choice", text="")
        elif isinstance(parameter, Categorical):
            column.prop(row, "choice", text=label)
        else:
            line = column.row(align=True)
            line.prop(row, "share", text=label, slider=True)
            line.prop(row, "value", text="")


CLASSES = (MetaSimDesignValue,)
