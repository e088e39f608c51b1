#!/usr/bin/env python3
"""Parameter tables of the plugin pages, generated from the plugins' parameter classes.

Each page (:data:`PAGES`) holds one table between the lines ``<!-- params:begin -->`` and
``<!-- params:end -->``; this script rewrites what lies between them from the parameter class:

- a pydantic model (``model_fields``: annotation, default, description, constraints ge/gt/le/lt...);
- a dataclass (fields and defaults; no description, no constraints);
- a callable (its signature: names, annotations, defaults), for a plugin without a parameter class.

Regions are loaded through the region registry (entry points ``lidar_weather_sim.regions``), filters
through their parameter classes in ``weather_filter``. Run with the workspace's environment
(``source .venv/env.sh``)::

    python scripts/param_docs.py                  # rewrite the tables
    python scripts/param_docs.py --check          # exit 1, one line naming the stale pages
    python scripts/param_docs.py --root DIR --only dror,cover      # the same pages under DIR
    python scripts/param_docs.py --page src/my_region/README.md=region:my_region   # any page
"""

from __future__ import annotations

import argparse
import dataclasses
import enum
import importlib
import importlib.util
import inspect
import json
import re
import sys
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
BEGIN = "<!-- params:begin -->"
END = "<!-- params:end -->"
HEADER = "| parameter | type | default | constraint | description |\n|---|---|---|---|---|"


class DocsError(Exception):
    """A page that cannot be generated (no markers, no file, a plugin that does not load)."""


@dataclass(frozen=True)
class Row:
    name: str
    type: str
    default: str
    constraint: str
    description: str


# -- parameter sources --------------------------------------------------------------------------


@dataclass(frozen=True)
class Source:
    """Where a page's parameters come from: ``spec`` is ``region:NAME``, ``filter:METHOD``,
    ``MODULE:QUALNAME`` or ``FILE.py:QUALNAME`` (a file relative to the repository)."""

    spec: str

    def load(self) -> tuple[Any, str]:
        """The parameter class (or callable) and the name it is documented from."""
        kind, _, rest = self.spec.partition(":")
        if not rest:
            raise DocsError(f"source {self.spec!r}: expected region:NAME, filter:METHOD or MODULE:QUALNAME")
        if kind == "region":
            from lidar_weather_sim.regions.base import REGISTRY

            params = REGISTRY.get(rest).Params
            return params, f"{params.__module__}.{params.__qualname__} (region '{rest}')"
        if kind == "filter":
            return filter_params(rest)
        if kind.endswith(".py"):
            return _attr(_module_from_file(REPO / kind), rest), f"{kind}:{rest}"
        return _attr(importlib.import_module(kind), rest), f"{kind}.{rest}"


#: Parameter classes of the filter methods (weather_filter.points), tried in order; the learned filter has
#: no class of its own yet: its parameters are those of ``LearnedFilter.load``.
FILTER_PARAMS = {
    "dror": ["weather_filter.points.dror:DRORParams"],
    "dsor": ["weather_filter.points.dsor:DSORParams"],
    "lior": ["weather_filter.points.lior:LIORParams"],
    "echo": ["weather_filter.points.echo:EchoParams"],
    "learned": ["weather_filter.learned.filter:LearnedParams", "weather_filter.learned.filter:LearnedFilter.load"],
}


def filter_params(method: str) -> tuple[Any, str]:
    if method not in FILTER_PARAMS:
        raise DocsError(f"unknown filter method {method!r} (known: {', '.join(FILTER_PARAMS)})")
    for spec in FILTER_PARAMS[method]:
        module, _, qualname = spec.partition(":")
        try:
            obj = _attr(importlib.import_module(module), qualname)
        except AttributeError:
            continue
        return obj, f"{module}.{qualname}"
    raise DocsError(f"filter '{method}': none of {', '.join(FILTER_PARAMS[method])} exists")


def _attr(obj: Any, qualname: str) -> Any:
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj


def _module_from_file(path: Path) -> types.ModuleType:
    """A module loaded from its file without putting its folder on ``sys.path`` (e.g. the region template)."""
    if not path.is_file():
        raise DocsError(f"{path}: no such file")
    name = "_param_docs_" + re.sub(r"\W", "_", str(path.relative_to(REPO) if path.is_relative_to(REPO) else path))
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


# -- rows ---------------------------------------------------------------------------------------


_MISSING = object()


def rows_of(obj: Any, prefix: str = "") -> list[Row]:
    """Table rows of a pydantic model class, a dataclass or a callable's signature; nested parameter sets
    (a field whose value is a model or dataclass) get a row of their own and one per field (``outer.inner``)."""
    if isinstance(obj, type) and hasattr(obj, "model_fields"):
        fields = [(name, f.annotation, _pydantic_default(f), _constraints(f.metadata, f.annotation), f.description or "")
                  for name, f in obj.model_fields.items()]  # fmt: skip
    elif isinstance(obj, type) and dataclasses.is_dataclass(obj):
        hints = _hints(obj)
        fields = [(f.name, hints.get(f.name, f.type), _dataclass_default(f), "", f.metadata.get("description", ""))
                  for f in dataclasses.fields(obj)]  # fmt: skip
    elif callable(obj):
        fields = []
        for p in inspect.signature(obj, eval_str=True).parameters.values():
            if p.name in ("self", "cls") or p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
                continue
            annotation = None if p.annotation is p.empty else p.annotation
            fields.append((p.name, annotation, _MISSING if p.default is p.empty else p.default, "", ""))
    else:
        raise DocsError(f"{obj!r}: not a pydantic model, a dataclass or a callable")
    rows = []
    for name, annotation, default, constraint, description in fields:
        full = prefix + name
        rows.append(Row(full, format_type(annotation), format_default(default), constraint, _one_line(description)))
        nested = _nested_class(annotation, default)
        if nested is not None:
            rows.extend(rows_of(nested, full + "."))
    return rows


def _hints(cls: type) -> dict[str, Any]:
    try:
        return typing.get_type_hints(cls, include_extras=True)
    except Exception:  # an annotation that does not evaluate: keep the strings
        return {}


def _pydantic_default(field) -> Any:
    if field.default_factory is not None:
        return field.default_factory()
    from pydantic_core import PydanticUndefined

    return _MISSING if field.default is PydanticUndefined else field.default


def _dataclass_default(field: dataclasses.Field) -> Any:
    if field.default is not dataclasses.MISSING:
        return field.default
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return _MISSING


def _is_params_class(tp: Any) -> bool:
    return isinstance(tp, type) and (hasattr(tp, "model_fields") or dataclasses.is_dataclass(tp))


def _nested_class(annotation: Any, default: Any) -> type | None:
    if _is_params_class(type(default)):
        return type(default)
    return annotation if _is_params_class(annotation) else None


# -- formatting ---------------------------------------------------------------------------------


def format_type(tp: Any) -> str:
    """``float``, ``int or null``, ``"auto" or "clear"``, ``list[int] or null``, ``mapping (LIORParams)``."""
    if tp is None:
        return ""
    if isinstance(tp, str):
        return tp.replace("None", "null").replace(" | ", " or ")
    if tp is type(None):
        return "null"
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is typing.Annotated:
        return format_type(args[0])
    if origin in (typing.Union, types.UnionType):
        parts = [format_type(a) for a in args if a is not type(None)]
        return " or ".join(parts + (["null"] if type(None) in args else []))
    if origin is typing.Literal:
        return " or ".join(json.dumps(_plain(a)) for a in args)
    if origin is not None:
        name = getattr(origin, "__name__", str(origin))
        return f"{name}[{', '.join(format_type(a) for a in args)}]"
    if _is_params_class(tp):
        return f"mapping ({tp.__name__})"
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return " or ".join(json.dumps(_plain(m.value)) for m in tp)
    if isinstance(tp, type) and issubclass(tp, Path):
        return "path"
    return getattr(tp, "__name__", str(tp))


def format_default(value: Any) -> str:
    """The default as written in YAML / JSON (``null``, ``true``, ``"clean"``, ``3.0``); a nested parameter
    set at its own defaults is ``{}``; no default: ``required``."""
    if value is _MISSING:
        return "required"
    if _is_params_class(type(value)):
        changed = _changed_fields(value)
        return f"`{json.dumps(changed, sort_keys=True)}`"
    return f"`{json.dumps(_plain(value))}`"


def _changed_fields(value: Any) -> dict:
    """Fields of a parameter set that differ from its class's defaults (``{}``: all defaults)."""
    cls = type(value)
    try:
        base = cls()
    except Exception:  # required fields: show them all
        base = None
    data = value.model_dump() if hasattr(value, "model_dump") else dataclasses.asdict(value)
    ref = {} if base is None else (base.model_dump() if hasattr(base, "model_dump") else dataclasses.asdict(base))
    return {k: _plain(v) for k, v in data.items() if k not in ref or ref[k] != v}


def _plain(value: Any) -> Any:
    if isinstance(value, enum.Enum):
        return _plain(value.value)
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (str, bool, int, float)) or value is None:
        return value
    return str(value)


_BOUNDS = (("ge", ">="), ("gt", ">"), ("le", "<="), ("lt", "<"))


def _constraints(metadata: list, annotation: Any = None) -> str:
    """Bounds, multiples, lengths and finiteness from pydantic field metadata, also where they sit in an
    ``Annotated`` type inside the annotation (``Annotated[float, Field(ge=0)] | None``)."""
    items = list(metadata) + _annotated_metadata(annotation)
    out: list[str] = []
    for item in items:
        for attr, symbol in _BOUNDS:  # annotated_types Ge, Gt, Le, Lt (or an Interval holding several)
            value = getattr(item, attr, None)
            if value is not None:
                out.append(f"{symbol} {_number(value)}")
        if type(item).__name__ == "MultipleOf":
            out.append(f"multiple of {_number(item.multiple_of)}")
        if type(item).__name__ == "MinLen":
            out.append(f"at least {item.min_length} items")
        if type(item).__name__ == "MaxLen":
            out.append(f"at most {item.max_length} items")
        if getattr(item, "allow_inf_nan", None) is False:
            out.append("finite")
    return ", ".join(dict.fromkeys(out))


def _annotated_metadata(tp: Any) -> list:
    found = []
    if typing.get_origin(tp) is typing.Annotated:
        for extra in typing.get_args(tp)[1:]:
            found.extend(getattr(extra, "metadata", None) or [extra])
        found.extend(_annotated_metadata(typing.get_args(tp)[0]))
    elif typing.get_origin(tp) in (typing.Union, types.UnionType):
        for arg in typing.get_args(tp):
            found.extend(_annotated_metadata(arg))
    return found


def _number(value: Any) -> str:
    return repr(value) if isinstance(value, (int, float)) else str(value)


def _one_line(text: str) -> str:
    """One table cell: whitespace collapsed, ``|`` escaped, ``<``/``>`` as entities (``<path>`` is no HTML tag)."""
    return " ".join(text.split()).replace("|", "\\|").replace("<", "&lt;").replace(">", "&gt;")


def render_table(obj: Any, source_name: str) -> str:
    """The block between the markers: a note naming the source, then the table."""
    lines = [f"<!-- generated by scripts/param_docs.py from {source_name}; edit the source, not this table -->", "",
             HEADER]
    for r in rows_of(obj):
        lines.append(f"| `{r.name}` | {r.type} | {r.default} | {r.constraint} | {r.description} |")
    return "\n".join(lines)


def replace_table(text: str, table: str, page: str) -> str:
    """``text`` with the block between the markers replaced by ``table``; the rest byte for byte."""
    if text.count(BEGIN) != 1 or text.count(END) != 1 or text.index(BEGIN) > text.index(END):
        raise DocsError(f"{page}: needs one '{BEGIN}' line and, after it, one '{END}' line")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n{table}\n\n{END}{tail}"


# -- pages --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Page:
    key: str
    path: str  # relative to the docs root (the repository by default)
    source: Source


PAGES = (
    Page("cover", "src/lidar_weather_sim/docs/regions/cover.md", Source("region:cover")),
    Page("atmosphere", "src/lidar_weather_sim/docs/regions/atmosphere.md", Source("region:atmosphere")),
    Page("faults", "src/lidar_weather_sim/docs/regions/faults.md", Source("region:faults")),
    Page("spray", "src/spray_particles/docs/spray_region.md", Source("region:spray")),
    Page("dror", "src/weather_filter/docs/filters/dror.md", Source("filter:dror")),
    Page("dsor", "src/weather_filter/docs/filters/dsor.md", Source("filter:dsor")),
    Page("lior", "src/weather_filter/docs/filters/lior.md", Source("filter:lior")),
    Page("echo", "src/weather_filter/docs/filters/echo.md", Source("filter:echo")),
    Page("learned", "src/weather_filter/docs/filters/learned.md", Source("filter:learned")),
    Page("template", "templates/region_template/README.md",
         Source("templates/region_template/region_template/region.py:TemplateRegion.Params")),
)


def process(pages: list[Page], root: Path, check: bool) -> list[str]:
    """Rewrite (or with ``check`` only compare) each page; the pages that were (or are) out of date."""
    stale = []
    for page in pages:
        path = Path(page.path) if Path(page.path).is_absolute() else root / page.path
        if not path.is_file():
            raise DocsError(f"{page.path}: no such page (under {root})")
        try:
            obj, name = page.source.load()
        except DocsError:
            raise
        except Exception as exc:  # an import error, an unknown region: name the page
            raise DocsError(f"{page.path}: cannot load the parameters of {page.source.spec} "
                            f"({type(exc).__name__}: {' '.join(str(exc).split())})") from None  # fmt: skip
        text = path.read_text()
        new = replace_table(text, render_table(obj, name), page.path)
        if new != text:
            stale.append(page.path)
            if not check:
                path.write_text(new)
    return stale


def _page_arg(text: str) -> Page:
    path, sep, spec = text.partition("=")
    if not sep or not path or not spec:
        raise argparse.ArgumentTypeError(f"{text!r}: expected PATH=SOURCE, e.g. README.md=region:my_region")
    return Page(path, path, Source(spec))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--check", action="store_true", help="change nothing; exit 1 naming the pages out of date")
    parser.add_argument("--root", type=Path, default=REPO, help="folder the page paths are relative to (default: the repository)")
    parser.add_argument("--only", default="", help=f"comma-separated page keys ({', '.join(p.key for p in PAGES)})")
    parser.add_argument("--page", action="append", type=_page_arg, default=[], metavar="PATH=SOURCE",
                        help="a page of your own instead of the built-in ones; SOURCE: region:NAME, filter:METHOD, "
                             "MODULE:QUALNAME or FILE.py:QUALNAME")  # fmt: skip
    args = parser.parse_args(argv)
    pages = list(args.page) or list(PAGES)
    if args.only:
        keys = [k.strip() for k in args.only.split(",") if k.strip()]
        unknown = sorted(set(keys) - {p.key for p in pages})
        if unknown:
            print(f"param_docs: unknown page key(s) {', '.join(unknown)} (known: {', '.join(p.key for p in pages)})",
                  file=sys.stderr)  # fmt: skip
            return 2
        pages = [p for p in pages if p.key in keys]
    try:
        stale = process(pages, args.root.resolve(), args.check)
    except DocsError as exc:
        print(f"param_docs: {exc}", file=sys.stderr)
        return 1
    if args.check and stale:
        print(f"param_docs: parameter table out of date in {', '.join(stale)} "
              f"(run python scripts/param_docs.py)", file=sys.stderr)  # fmt: skip
        return 1
    if not args.check:
        for path in stale:
            print(f"param_docs: rewrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
