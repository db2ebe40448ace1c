"""The machine profile's schema: every table and key, its type, bounds, default and what to write.

Declared with pydantic models; :func:`validate` checks a parsed TOML profile and
returns a :class:`Profile`, or raises one :class:`MachineError` line naming the
file, the key as a dotted path (``axes.x.max_velocity``, ``pen[2].width``: the
second ``[[pen]]``, counted from 1 like the pen numbers the operator is told)
and the fix, taken from the field's description. Whether the numbers describe a
plausible plotter (units slipped, a home outside the work area, the step rate)
is :mod:`doodlecam.plausible`'s question, asked of the Machine built from this.
"""

from __future__ import annotations

import difflib
import types
import typing
from typing import Annotated, Any, Union

from pydantic import BaseModel, ConfigDict, Discriminator, Field, Strict, Tag, ValidationError, create_model, field_validator
from pydantic_core import PydanticCustomError

from doodlecam.errors import MachineError, did_you_mean
from doodlecam.options import LAYOUT_DEFAULTS, ORDER_DEFAULTS, SOLVERS, TRAVEL_ALIASES, TRAVEL_LAWS, travel_law_name

# TOML's own types, without pydantic's lax conversions ("1.5" or true is no number)
Num = Annotated[float, Strict()]
Int = Annotated[int, Strict()]
Text = Annotated[str, Strict()]


def _unknown(known) -> PydanticCustomError:
    """A name that is not one of ``known``: the formatter adds the did-you-mean and the list."""
    return PydanticCustomError("unknown_name", "unknown name", {"known": tuple(known)})


class Table(BaseModel):
    """A TOML table: unknown keys are refused (with a did-you-mean), numbers are finite."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class MachineTable(Table):
    name: Text = Field(min_length=1, description='the profile\'s name, e.g. "my-plotter"')
    description: Text = Field("", description="one line about the machine")
    kinematics: Text = Field("cartesian", description="a kinematics plugin's name (see 'doodlecam plugins')")
    solver: Text = Field("reach", description=f"one of {', '.join(SOLVERS)}")
    smoothing: Num = Field(1.0, gt=0, description="the smoothing QP's weight against time, e.g. 1.0")

    @field_validator("solver")
    @classmethod
    def _solver(cls, v: str) -> str:
        if v not in SOLVERS:
            raise _unknown(SOLVERS)
        return v


class WorkArea(Table):
    width: Num = Field(gt=0, description="the travel in x in mm, e.g. 297")
    height: Num = Field(gt=0, description="the travel in y in mm, e.g. 210")
    margin: Num = Field(10.0, ge=0, description="mm kept clear at each edge, e.g. 10")
    home: tuple[Num, Num] = Field((0.0, 0.0), description="two numbers [x, y] in mm, e.g. [0, 0]")

    @field_validator("margin")
    @classmethod
    def _room(cls, v: float, info) -> float:
        size = [info.data[k] for k in ("width", "height") if k in info.data]
        if size and 2 * v >= min(size):
            raise PydanticCustomError("no_room", "leaves no room to draw", {"fix": "make it smaller than half the work area"})
        return v


class Axis(Table):
    steps_per_mm: Num = Field(gt=0, description="motor steps per mm of travel, e.g. 80")
    max_velocity: Num = Field(gt=0, description="the axis' top speed in mm/s, e.g. 100")
    max_acceleration: Num = Field(gt=0, description="the axis' top acceleration in mm/s^2, e.g. 1000")


class Axes(Table):
    x: Axis
    y: Axis


class Pen(Table):
    width: Num = Field(0.5, gt=0, description="the line width in mm, e.g. 0.5 (shorter strokes are dropped)")
    up_delay: Num = Field(0.1, ge=0, description="seconds to lift the pen and settle, e.g. 0.15")
    down_delay: Num = Field(0.1, ge=0, description="seconds to lower the pen and settle, e.g. 0.15")
    max_speed: Annotated[Num, Field(gt=0)] | None = Field(None, description="a pen-speed cap in mm/s, e.g. 100")
    max_accel: Annotated[Num, Field(gt=0)] | None = Field(None, description="a cap on each axis' acceleration "
                                                                            "in mm/s^2 while drawing, e.g. 500")


class PenEntry(Pen):
    """One ``[[pen]]`` of a machine with several pens (or one changed by hand)."""

    name: Text = Field("", description='a name the operator knows the pen by, e.g. "fineliner"')
    colour: Text = Field("", description='a CSS colour, e.g. "red" or "#c00000"')
    color: Text = Field("", description='a CSS colour, e.g. "red" (the same as colour)')
    layers: list[Text] = Field([], description='the drawing\'s layers this pen draws, e.g. ["outline"]')


def _pens_unique(pens: list[PenEntry]) -> list[PenEntry]:
    seen: dict[str, int] = {}
    for k, p in enumerate(pens, 1):
        if p.name and p.name.lower() in seen:
            raise PydanticCustomError("same_name", "is taken: two [[pen]] entries are named '{name}'",
                                      {"name": p.name, "value": p.name, "at": (k - 1, "name"),
                                       "fix": "give each pen its own name"})
        seen[p.name.lower()] = k
    return pens


PenList = Annotated[list[PenEntry], Field(min_length=1)]


class Travel(Table):
    speed: Annotated[Num, Field(gt=0)] | None = Field(None, description="mm/s per axis for pen-up moves, e.g. 100")
    law: Text = Field("trapezoid", description=f"one of {', '.join(list(TRAVEL_LAWS) + list(TRAVEL_ALIASES))}")

    @field_validator("law")
    @classmethod
    def _law(cls, v: str) -> str:
        try:
            return travel_law_name(v)
        except ValueError:
            raise _unknown(list(TRAVEL_LAWS) + list(TRAVEL_ALIASES)) from None


class Sampling(Table):
    delta_time: Num = Field(0.04, gt=0, description="the velocity sample period in seconds, e.g. 0.04 (40 ms)")
    path_tolerance: Annotated[Num, Field(ge=0)] | None = Field(
        None, description="mm the pen may stray from the curve between samples, e.g. 0.1 (0: not enforced)")


class Fit(Table):
    degree: Int = Field(3, ge=2, le=5, description="2 to 5 (3 is the report's cubic URBS; "
                                                   "2 and up keep the velocity continuous)")
    tolerance: Num = Field(0.1, gt=0, description="mm the spline may stray from the traced line, e.g. 0.1")


# [layout] and [order]: their keys here, their values checked by doodlecam.options (shared with the CLI's options)
Layout = create_model("Layout", __base__=Table, **{k: (Any, None) for k in LAYOUT_DEFAULTS})
Order = create_model("Order", __base__=Table, **{k: (Any, None) for k in ORDER_DEFAULTS})
PluginTables = dict[str, dict[str, Any]]  # [trace.NAME], [post.NAME], [transport.NAME]: each plugin checks its own


class Profile(Table):
    machine: MachineTable
    work_area: WorkArea
    axes: Axes
    # one [pen] table, or a [[pen]] list (the tags tell the two apart in an error's path)
    pen: Annotated[Union[Annotated[Pen, Tag("[pen]")], Annotated[PenList, Tag("[[pen]]")]],
                   Discriminator(lambda v: "[[pen]]" if isinstance(v, list) else "[pen]")] = Pen()
    travel: Travel = Travel()
    sampling: Sampling = Sampling()
    fit: Fit = Fit()
    layout: Layout = Layout()  # type: ignore[valid-type]
    order: Order = Order()  # type: ignore[valid-type]
    kinematics: dict[str, Any] = Field({}, description="a table of the kinematics plugin's parameters (the plugin's "
                                                        "name goes under [machine]: kinematics = \"fivebar\")")
    trace: PluginTables = Field({}, description="a table of options per tracer, e.g. [trace.edges]")
    post: PluginTables = Field({}, description="a table of options per post, e.g. [post.gcode]")
    transport: PluginTables = Field({}, description="a table of options per transport, e.g. [transport.udp]")

    @field_validator("pen")
    @classmethod
    def _pens(cls, v):
        return _pens_unique(v) if isinstance(v, list) else v


def validate(data: dict[str, Any], path: str, model: type[BaseModel] = Profile, prefix: tuple = ()) -> BaseModel:
    """``data`` checked against ``model``, or one MachineError line for its first problem.
    ``prefix``: where ``data`` sits in the profile (("kinematics",) for a plugin's table)."""
    try:
        return model.model_validate(data)
    except ValidationError as e:
        # an unknown key first: misspelt, it is also the "missing" key it was meant to be
        errors = sorted(e.errors(include_url=False), key=lambda x: x["type"] != "extra_forbidden")
        first, rest = errors[0], errors[1:]
        if first["type"] == "extra_forbidden":
            rest = [x for x in rest if not (x["type"] == "missing" and difflib.get_close_matches(
                str(x["loc"][-1]), [str(first["loc"][-1])], n=1, cutoff=0.6) and x["loc"][:-1] == first["loc"][:-1])]
        more = f" (and {len(rest)} more {'problem' if len(rest) == 1 else 'problems'})" if rest else ""
        raise MachineError(f"{path}: {message(first, model, prefix)}{more}") from None


# ---------------------------------------------------------------- one line per error

def _ordinal(k: int) -> str:
    return f"{k}{'th' if 10 <= k % 100 <= 20 else {1: 'st', 2: 'nd', 3: 'rd'}.get(k % 10, 'th')}"


def dotted(loc) -> str:
    """('pen', '[[pen]]', 1, 'width') -> 'pen[2].width' (list items counted from 1)."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part + 1}]"
        elif not part.startswith("["):  # a tag of the pen union
            out += f".{part}" if out else part
    return out


def _header(loc) -> str:
    """The TOML header a key is written under: '[axes.y]', 'the 2nd [[pen]]', 'the top of the file'."""
    parts = [p for p in loc if not (isinstance(p, str) and p.startswith("["))]
    if not parts:
        return "the top of the file"
    if isinstance(parts[-1], int):
        return f"the {_ordinal(parts[-1] + 1)} [[{dotted(parts[:-1])}]]"
    return f"[{dotted(parts)}]"


def _unwrap(ann) -> list:
    """The types an annotation admits, Annotated, Optional and unions taken apart."""
    if typing.get_origin(ann) is Annotated:
        return _unwrap(typing.get_args(ann)[0])
    if typing.get_origin(ann) in (Union, types.UnionType):
        return [t for a in typing.get_args(ann) for t in _unwrap(a)]
    return [ann]


def _node(model, loc):
    """(the table model at ``loc`` or None, the field there or None), through [[pen]] lists and tags."""
    ann, field = model, None
    for part in loc:
        if isinstance(part, str) and part.startswith("["):  # a tag of the pen union
            continue
        kinds = _unwrap(ann)
        if isinstance(part, int):
            ann = next((typing.get_args(k)[0] for k in kinds if typing.get_origin(k) is list), None)
            field = None
        else:
            tables = [k for k in kinds if _is_table(k)]
            field = tables[0].model_fields.get(part) if tables else None
            ann = field.annotation if field is not None else None
        if ann is None:
            return None, None
    return next((k for k in _unwrap(ann) if _is_table(k)), None), field


def _is_table(t) -> bool:
    return isinstance(t, type) and issubclass(t, BaseModel)


def _where_else(model, key: str) -> list[str]:
    """The tables that have a key of this name ('width' -> [work_area], [pen])."""
    out = []
    for name, f in model.model_fields.items():
        for t in _unwrap(f.annotation):
            if typing.get_origin(t) is list:
                t = typing.get_args(t)[0]
            for sub in _unwrap(t):
                if isinstance(sub, type) and issubclass(sub, BaseModel):
                    if key in sub.model_fields:
                        out.append(f"[{name}]")
                    out += [f"[{name}.{w[1:-1]}]" for w in _where_else(sub, key)]
    return list(dict.fromkeys(out))


def _shown(value) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


_TYPES = {"float_type": "is not a number", "int_type": "is not a whole number",
          "string_type": "is not text (put it in quotes)", "bool_type": "is not true or false",
          "list_type": "is not a list [...]", "tuple_type": "is not a list [...]", "dict_type": "is not a table",
          "model_type": "is not a table", "finite_number": "is not a finite number",
          "string_too_short": "is empty", "too_short": "has too few values", "too_long": "has too many values"}
_BOUNDS = {"greater_than": ("more than", "gt"), "greater_than_equal": ("at least", "ge"),
           "less_than": ("less than", "lt"), "less_than_equal": ("at most", "le")}


def message(err: dict, model: type[BaseModel] = Profile, prefix: tuple = ()) -> str:
    """One pydantic error as '<key>[ = value] <what is wrong>; <what to write>'."""
    kind, ctx = err["type"], err.get("ctx") or {}
    loc = tuple(err["loc"]) + tuple(ctx.get("at", ()))
    key = dotted(prefix + loc)
    parent = loc[:-1]
    node, field = _node(model, loc)
    if kind == "missing" and isinstance(loc[-1], int):  # a [x, y] pair with one number
        node, field, kind, loc, key = None, _node(model, parent)[1], "too_short", parent, dotted(prefix + parent)
    if field is None and loc and isinstance(loc[-1], int):  # an item of a list: what the list holds
        field = _node(model, parent)[1]
    fix = f"give {field.description}" if field is not None and field.description else "fix the profile"
    if kind == "extra_forbidden":
        return _unknown_key(err, model, prefix, loc)
    if kind == "missing":
        if node is not None:
            needed = ", ".join(k for k, f in node.model_fields.items() if f.is_required())
            return f"missing table [{key}]; add it with the keys {needed} (see 'doodlecam machines new')"
        return f"{key} is missing; add it under {_header(prefix + parent)}: {loc[-1]} = {fix.removeprefix('give ')}"
    shown = f" = {_shown(ctx.get('value', err['input']))}"
    if kind == "unknown_name":
        known = ctx["known"]
        return f"{key}{shown} is unknown{did_you_mean(str(err['input']), known)}; use one of {', '.join(known)}"
    if kind in _BOUNDS:
        words, bound = _BOUNDS[kind]
        limit = {"gt": "positive", "ge": "0 or more"}.get(bound) if ctx[bound] == 0 else None
        return f"{key}{shown} must be {limit or f'{words} {_shown(ctx[bound])}'}; {fix}"
    if kind == "too_short" and key == dotted(prefix + ("pen",)):
        return f"[[{key}]] is empty; give at least one pen, or use a single [pen] table"
    if kind in ("dict_type", "model_type") and fix == "fix the profile":
        fix = (f"write it as a [[{dotted(prefix + parent)}]] table" if isinstance(loc[-1], int)
               else f"write it as a table: [{key}]") + " with its keys on the lines below"
    if kind in _TYPES:
        return f"{key}{shown} {_TYPES[kind]}; {fix}"
    if "fix" in ctx:  # the schema's own checks
        return f"{key}{shown} {err['msg']}; {ctx['fix']}"
    return f"{key}{shown}: {err['msg']}; {fix}"


def _unknown_key(err: dict, model, prefix: tuple, loc: tuple) -> str:
    """'unknown key axes.x.max_accleration (did you mean 'max_acceleration'?)', 'unknown table [axis] ...'."""
    parent, leaf = loc[:-1], str(loc[-1])
    owner = _node(model, parent)[0] if parent else model
    known = list(owner.model_fields) if owner is not None else []
    is_table = isinstance(err.get("input"), dict)
    key = dotted(prefix + loc)
    top = not parent and not prefix  # the file's own top level: tables
    if top and not is_table:  # a key above every table: the tables it belongs in
        homes = _where_else(model, leaf)
        hint = f" (it belongs under {' or '.join(homes)})" if homes else ""
    elif is_table:  # shown as the header to write: [axes.x]
        near = difflib.get_close_matches(leaf.casefold(), [k.casefold() for k in known], n=1, cutoff=0.6)
        hint = f" (did you mean [{dotted(prefix + parent + (near[0],))}]?)" if near else ""
    else:
        hint = did_you_mean(leaf, known)
    if not hint:
        listed = ", ".join(f"[{dotted(prefix + parent + (k,))}]" if top or _node(model, parent + (k,))[0] else k
                           for k in known)
        hint = f" (known here: {listed})"
    return f"unknown {f'table [{key}]' if is_table else f'key {key}'}{hint}; rename or remove it"
