"""The filters evtools has, one line each, and what is derived from their declarations: the parameters by name,
the README's table, the API's signature and docstring."""

from __future__ import annotations

import inspect
import textwrap
from typing import Any

from evtools.filters.baf import Baf
from evtools.filters.dwf import Dwf
from evtools.filters.hotpixel import HotPixel
from evtools.filters.mlpf import Mlpf
from evtools.filters.order_n import OrderN
from evtools.filters.refractory import Refractory
from evtools.filters.spec import PRESETS, Filter, Param
from evtools.filters.stcf import Stcf
from evtools.filters.ynoise import YNoise

REGISTRY: tuple[type[Filter], ...] = (
    Baf,
    Stcf,
    Dwf,
    OrderN,
    Refractory,
    HotPixel,
    Mlpf,
    YNoise,
)
"""Every filter, in the order the help and the README list them."""

METHODS = tuple(f.name for f in REGISTRY)
BY_NAME = {f.name: f for f in REGISTRY}


def parameters() -> dict[str, list[tuple[type[Filter], Param]]]:
    """Parameter name -> (filter, its declaration) for every filter that has it, in registry order."""
    found: dict[str, list[tuple[type[Filter], Param]]] = {}
    for f in REGISTRY:
        for param in f.params:
            found.setdefault(param.name, []).append((f, param))
    return found


def _value(value: Any) -> str:
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, float) and value == int(value):
        return str(int(value))
    return str(value)


def default_text(f: type[Filter], name: str) -> str:
    """``f``'s defaults of parameter ``name`` per preset: ``"10000; dv 2000; jaer 25000"``."""
    own = f.defaults["evtools"].get(name)
    text = f.default_notes.get(name) if own is None else _value(own)
    others = [f"{preset} {_value(f.defaults[preset][name])}" for preset in PRESETS[1:]
              if name in f.defaults.get(preset, {}) and f.defaults[preset][name] != own]
    return "; ".join([text or "none", *others])


def option_help(name: str) -> str:
    """The command-line help of parameter ``name``: what it does for each filter that has it, with defaults;
    filters with the same text share it (``stcf, orderN: correlation window, us [10000; jaer 25000]``)."""
    groups: dict[str, list[str]] = {}
    for f, param in parameters()[name]:
        groups.setdefault(f"{param.help} [{default_text(f, name)}]", []).append(f.name)
    return " ".join(f"{', '.join(names)}: {text}." for text, names in groups.items())


def markdown_table() -> str:
    """The README's table of filters: when each keeps an event, and its parameters with evtools' defaults."""
    rows = ["| method | keeps an event when | parameters (evtools defaults) |", "|---|---|---|"]
    for f in REGISTRY:
        shown = []
        for param in f.params:
            if not param.cli:
                continue
            value = f.defaults["evtools"][param.name]
            if param.kind == "bool":  # on: its option; off: the off form where there is one
                forms = (param.flag or param.option).split("/")
                if value or len(forms) > 1:
                    shown.append(f"`{forms[0] if value else forms[1]}`")
            elif value is None:
                shown.append(f"`{param.option}` {f.default_notes.get(param.name, 'none')}")
            else:
                shown.append(f"`{param.option} {_value(value)}`")
        text = " ".join(shown)
        rows.append(f"| `{f.name}` | {f.keeps} | {text}{f' ({f.defaults_from})' if f.defaults_from else ''} |")
    return "\n".join(rows)


def _methods_text() -> str:
    """Every method by name, with whose it is: ``"``baf`` (Delbruck 2008), ``stcf`` (...), ..."``."""
    return ", ".join(f"``{f.name}``" + (f" ({f.reference})" if f.reference else "") for f in REGISTRY)


def _parameters_doc() -> str:
    """The filters' parameters as a numpy-style docstring section (name, kind, what each filter does with it)."""
    lines = ["    Filter parameters", "    -----------------"]
    for name, uses in parameters().items():
        lines.append(f"    {name} : {uses[0][1].kind}, optional")
        for f, param in uses:
            lines += textwrap.wrap(f"{f.name}: {param.help} [{default_text(f, name)}].", 116, initial_indent=" " * 8,
                                   subsequent_indent=" " * 10)
    return "\n".join(lines) + "\n"


def document(target, *leading: str, methods: str = "methods") -> None:
    """Give ``target``, which takes the filters' parameters as ``**params``, their keywords: in its signature when
    it is a function (``leading`` positional names, then ``methods`` defaulting to "baf", then ``preset`` and every
    parameter, None: the preset's default), for ``help()`` and tab completion; in its docstring, a section of them
    (before its Examples, if any) and the list of methods where it says ``METHODS_TEXT``."""
    if inspect.isfunction(target):
        kind = inspect.Parameter.POSITIONAL_OR_KEYWORD
        keyword = inspect.Parameter.KEYWORD_ONLY
        target.__signature__ = inspect.Signature(
            [*(inspect.Parameter(name, kind) for name in leading), inspect.Parameter(methods, kind, default="baf"),
             inspect.Parameter("preset", keyword, default="evtools", annotation=str),
             *(inspect.Parameter(name, keyword, default=None) for name in parameters())])
    doc = (target.__doc__ or "").rstrip() + "\n"
    listed = textwrap.fill(f"One filter or a comma-separated chain (:data:`evtools.filters.METHODS`): "
                           f"{_methods_text()} (README, section Bafilter).", 116, initial_indent=" " * 8,
                           subsequent_indent=" " * 8)
    doc = doc.replace(" " * 8 + "METHODS_TEXT", listed)
    head, examples = doc.split("    Examples\n") if "    Examples\n" in doc else (doc, None)
    doc = head.rstrip() + "\n\n" + _parameters_doc()
    target.__doc__ = doc if examples is None else doc + "\n    Examples\n" + examples
