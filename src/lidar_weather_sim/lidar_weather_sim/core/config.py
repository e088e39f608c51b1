"""YAML configuration validated by pydantic models; errors name file, key and value.

Every configurable component (sensor profile, scenario, region) defines one
:class:`ConfigModel` subclass whose field descriptions give unit and range;
:func:`load_yaml` reads a file into it.
"""

from __future__ import annotations

import types
import typing
from pathlib import Path
from typing import Any, ClassVar, TypeVar

import pydantic
import yaml
from pydantic_core import PydanticCustomError


def _is_number(annotation: Any) -> bool:
    """The annotation takes int or float (directly, Optional, a union or Annotated) and not bool."""
    if annotation in (int, float):
        return True
    args = typing.get_args(annotation)
    if typing.get_origin(annotation) is typing.Annotated:
        return _is_number(args[0])
    return bool(args) and bool not in args and typing.get_origin(annotation) in (typing.Union, types.UnionType) \
        and any(_is_number(a) for a in args)  # fmt: skip


class ConfigModel(pydantic.BaseModel):
    """Base of all configuration schemas: unknown keys are errors, instances are immutable, every
    number is finite (``.inf`` / ``.nan`` are refused) and a boolean is never taken for a number.

    ``moved_keys`` maps a key that moved or was removed to where it went; such a key is refused
    with that one line instead of "unknown key".
    """

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    moved_keys: ClassVar[dict[str, str]] = {}

    @pydantic.field_validator("*", mode="before")
    @classmethod
    def _refuse_bool_for_number(cls, value: Any, info: pydantic.ValidationInfo) -> Any:
        if isinstance(value, bool) and info.field_name and _is_number(cls.model_fields[info.field_name].annotation):
            raise PydanticCustomError("bool_number", "a boolean is not a number")
        return value

    @pydantic.model_validator(mode="before")
    @classmethod
    def _refuse_moved_keys(cls, data: Any) -> Any:
        if cls.moved_keys and isinstance(data, dict):
            for key, where in cls.moved_keys.items():
                if key in data:
                    raise PydanticCustomError("moved_key", "{where}", {"key": key, "where": where})
        return data


M = TypeVar("M", bound=pydantic.BaseModel)


class ConfigError(ValueError):
    """A configuration file that cannot be read or does not match its schema."""


def _key_path(loc: tuple[Any, ...]) -> str:
    return ".".join(str(part) for part in loc) or "<top level>"


def _lookup(data: Any, loc: tuple[Any, ...]) -> Any:
    for part in loc:
        try:
            data = data[part]
        except (KeyError, IndexError, TypeError):
            return None
    return data


def format_validation_error(source: str, error: pydantic.ValidationError, data: Any) -> str:
    """One line per problem: ``source: key 'a.b': value 3: reason``."""
    lines = []
    for item in error.errors():
        loc = tuple(item["loc"])
        key = _key_path(loc)
        if item["type"] == "moved_key":
            lines.append(f"{source}: key '{_key_path(loc + (item['ctx']['key'],))}' {item['ctx']['where']}")
        elif item["type"] == "extra_forbidden":
            lines.append(f"{source}: unknown key '{key}'")
        elif item["type"] == "missing":
            lines.append(f"{source}: missing key '{key}'")
        elif not loc:  # a model-level check: its message names the keys
            lines.append(f"{source}: {item['msg'].removeprefix('Value error, ')}")
        elif isinstance(_lookup(data, loc), (dict, list)):  # a check of a whole block: the reason, not the block
            lines.append(f"{source}: key '{key}': {item['msg'].removeprefix('Value error, ')}")
        else:
            lines.append(f"{source}: key '{key}': value {_lookup(data, loc)!r}: {item['msg']}")
    return "\n".join(lines)


def validate(data: Any, model: type[M], source: str = "<data>") -> M:
    """Validate a parsed mapping against ``model``; raise :class:`ConfigError` naming the key."""
    try:
        return model.model_validate(data)
    except pydantic.ValidationError as exc:
        raise ConfigError(format_validation_error(source, exc, data)) from None


def load_yaml(path: str | Path, model: type[M]) -> M:
    """Read ``path`` and validate it against ``model``."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise ConfigError(f"{path}:{where}: invalid YAML: {getattr(exc, 'problem', exc)}") from None
    except RecursionError:
        raise ConfigError(f"{path}: invalid YAML: nested too deeply") from None
    if data is None:
        data = {}
    try:
        return validate(data, model, str(path))
    except RecursionError:
        raise ConfigError(f"{path}: nested too deeply for a {model.__name__}") from None


def load_named(name_or_path: str | Path, directory: Path, model: type[M], kind: str) -> M:
    """Load ``directory/<name>.yaml`` or, for a ``.yaml``/``.yml`` argument, that path.

    An unknown name raises :class:`ConfigError` listing the known ``kind`` names.
    """
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml"):
        path = directory / f"{name_or_path}.yaml"
        if not path.exists():
            known = sorted(p.stem for p in directory.glob("*.yaml"))
            raise ConfigError(f"unknown {kind} '{name_or_path}' (known: {', '.join(known)})")
    return load_yaml(path, model)


def dump_yaml(config: pydantic.BaseModel) -> str:
    """The configuration as YAML (defaults included), e.g. for ``dump-config``."""
    return yaml.safe_dump(config.model_dump(mode="json"), sort_keys=False)
