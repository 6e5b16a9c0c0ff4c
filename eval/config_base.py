"""The shared pieces of the YAML configuration (`config`): the frozen pydantic model base every
config model derives from, the value types and validators several of them use (a graph drift, a
parameter dataclass as a config value, a dataclass field's rule on a config value), and the
helpers that read a YAML file (refusing duplicate keys) and validate it into a model, turning
pydantic's errors into one-line `ConfigError`s that name each key's path.
"""

from __future__ import annotations

import dataclasses
import functools
import typing
from dataclasses import replace
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import yaml
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    PlainSerializer,
    PlainValidator,
    ValidationError,
    model_validator,
)

from tcaff_gtsam.errors import ConfigError
from tcaff_gtsam.params import ParameterError

#: a name that becomes a file or folder name: letters, digits, '_', '.' and '-', not dots alone
#: ('.' and '..' name folders that exist: results would be written beside or above --output)
FILE_NAME = r"^[A-Za-z0-9_.-]*[A-Za-z0-9_-][A-Za-z0-9_.-]*$"


def _check_drift(value: tuple[float, float] | None) -> tuple[float, float] | None:
    if value is not None and not (value[0] > 0 and value[1] > 0):
        raise ValueError(f"need (metres > 0, degrees > 0), got {value}")
    return value


#: an iSAM2 between-step drift (metres, degrees), or None
GraphDrift = Annotated[tuple[float, float] | None, AfterValidator(_check_drift)]


def _leaf_types(annotation: Any) -> set:
    """The plain types a field's type is made of, through unions, containers, `Annotated` and
    `Literal` (its values' types); config models and parameter dataclasses are leaves, which
    check their own fields."""
    args = typing.get_args(annotation)
    if typing.get_origin(annotation) is Literal:
        return {type(a) for a in args}
    if typing.get_origin(annotation) is Annotated:
        args = args[:1]
    return set().union(*map(_leaf_types, args)) if args else {annotation}


def _bool_inside(value: Any) -> tuple[tuple[str, ...], bool] | None:
    """The first bool in `value` (a YAML value) and its key path there, or None."""
    if isinstance(value, bool):
        return (), value
    items = (value.items() if isinstance(value, dict)
             else enumerate(value) if isinstance(value, (list, tuple)) else ())
    for key, item in items:
        inner = _bool_inside(item)
        if inner is not None:
            return (str(key), *inner[0]), inner[1]
    return None


@functools.cache
def _numeric_fields(model: type[BaseModel]) -> frozenset[str]:
    """The fields of `model` whose type takes numbers (int or float) and no bool."""
    return frozenset(name for name, field in model.model_fields.items()
                     if (leaves := _leaf_types(field.annotation)) & {int, float}
                     and not leaves & {bool, Any})


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    @model_validator(mode="before")
    @classmethod
    def _no_bool_for_a_number(cls, data: Any) -> Any:
        """pydantic takes `true` for 1 where a number is expected (`duration: yes` would be a
        one-second run): a bool is refused in a field of numbers."""
        if isinstance(data, dict):
            for name in _numeric_fields(cls) & data.keys():
                found = _bool_inside(data[name])
                if found is not None:
                    path, value = found
                    raise _EntryError((name, *path), "must be a number, not true/false", value)
        return data


class _Finite(_Model):
    """A config in which no number may be infinite or NaN (YAML's .inf and .nan): pydantic
    takes them where a bound is only below, and neither the simulator nor a data set's run
    can use one (an infinite range, drift or span)."""

    model_config = ConfigDict(allow_inf_nan=False)


# -- parameter dataclasses as config values ----------------------------------------------------


class _EntryError(ValueError):
    """A bad entry of a mapping a parameter object is built from; `keys` (from the mapping
    down) extend the key path of the error, `value` is the entry's value (None with
    `show_value` False: an unknown key)."""

    def __init__(self, keys: tuple[str, ...], message: str, value: Any = None,
                 show_value: bool = True) -> None:
        super().__init__(f"{'.'.join(keys)}: {message}")
        self.keys, self.message, self.value, self.show_value = keys, message, value, show_value

    def within(self, key: str) -> _EntryError:
        return _EntryError((key, *self.keys), self.message, self.value, self.show_value)


def _build(cls: type, data: Any, fixed: dict[str, str]) -> Any:
    """A `cls` (a frozen parameter dataclass) from a mapping of some of its fields, the rest
    keeping the dataclass's defaults; an instance passes as it is. Fields in `fixed` (name ->
    why) belong to the run, not to this mapping, and are refused unless left at the default."""
    if isinstance(data, cls):
        default = cls()
        for name, why in fixed.items():
            if replace(default, **{name: getattr(data, name)}) != default:
                raise _EntryError((name,), why, getattr(data, name))
        return data
    if not isinstance(data, dict):
        raise ValueError(f"must be a mapping of {cls.__name__} fields")
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    types = typing.get_type_hints(cls)
    kwargs = {}
    for key, value in data.items():
        if key in fixed:
            raise _EntryError((key,), fixed[key], value)
        if key not in names:
            raise _EntryError((str(key),), "Extra inputs are not permitted", show_value=False)
        if dataclasses.is_dataclass(types[key]):
            try:
                value = _build(types[key], value, {})
            except _EntryError as exc:
                raise exc.within(key) from None
            except ValueError as exc:
                raise _EntryError((key,), str(exc), value) from None
        kwargs[key] = value
    try:
        return cls(**kwargs)
    except ParameterError as exc:
        raise _EntryError((exc.name,), exc.rule, exc.value) from None


def _plain(value: Any, skip: tuple[str, ...] = ()) -> Any:
    """`value` as YAML-safe data: dataclasses as mappings of their fields (but `skip`), arrays
    and tuples as lists, numpy scalars as Python numbers."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)
                if f.init and f.name not in skip}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _params(cls: type, **fixed: str) -> Any:
    """The config type of parameter dataclass `cls`: in YAML a mapping of some of its fields,
    in Python an instance; written out (JSON mode) as the mapping of all its fields but the
    `fixed` ones (name -> why they are set elsewhere), which loads again as the same object."""
    return Annotated[cls, PlainValidator(lambda data: _build(cls, data, fixed)),
                     PlainSerializer(lambda value: _plain(value, tuple(fixed)), when_used="json")]


def _rule_of(cls: type, name: str) -> AfterValidator:
    """Checks a config value (None passes) by the rule of field `name` of `cls`, so that the
    rule is written once, in the dataclass."""

    def check(value: Any) -> Any:
        if value is not None:
            try:
                cls(**{name: value})
            except ParameterError as exc:
                raise ValueError(exc.rule) from None
        return value

    return AfterValidator(check)


# -- reading and validating YAML ---------------------------------------------------------------


#: the `kind`s of the scenario layouts, tags of a union branch in pydantic's error paths
_LAYOUT_KINDS = ("indoor_return", "same_direction", "opposite_directions", "room", "grid")


def _path(loc: tuple) -> str:
    """The key path of a pydantic error location, without union-branch and validator tags."""
    parts: list[str] = []
    for k, item in enumerate(loc):
        item = str(item)
        if (item.startswith("function-") or "[" in item or item[:1].isupper()
                or item == "str" or (item in _LAYOUT_KINDS and k and loc[k - 1] == "layout")):
            continue
        parts.append(item)
    return ".".join(parts) or "(top level)"


def _format(source: str, error: ValidationError) -> str:
    items = error.errors()
    # a name-or-inline field fails as a string too; that branch's complaint is noise
    detailed = [e for e in items if not (e["type"] == "string_type" and "str" in e["loc"])]
    parts = []
    for item in detailed or items:
        path, value = _path(item["loc"]), item.get("input")
        message = item["msg"].removeprefix("Value error, ")
        show = item["type"] not in ("missing", "extra_forbidden") and not isinstance(value, dict)
        entry = item.get("ctx", {}).get("error")
        if isinstance(entry, _EntryError):
            # after _path, which drops capitalised parts (union tags) and fields such as Q
            path = ".".join([*(p for p in [path] if p != "(top level)"), *entry.keys])
            message, value, show = entry.message, entry.value, entry.show_value
        if show:
            message += f" (got {value!r})"
        parts.append(f"{path}: {message}")
    return f"{source}: " + "; ".join(dict.fromkeys(parts))


class _DuplicateKeyError(yaml.constructor.ConstructorError):
    """A key given twice in one YAML mapping."""

    def __init__(self, key: Any, mark: yaml.Mark | None) -> None:
        super().__init__(problem=f"duplicate key {key!r}", problem_mark=mark)
        self.key, self.line = key, None if mark is None else mark.line + 1


class UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a key given twice in one mapping (the plain loader keeps
    the last value silently). Keys brought in by a merge (`<<: *base`) may be overridden."""

    def construct_mapping(self, node: yaml.Node, deep: bool = False) -> dict:
        if isinstance(node, yaml.MappingNode):
            seen: set = set()
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    if key in seen:
                        raise _DuplicateKeyError(key, key_node.start_mark)
                    seen.add(key)
                except TypeError:  # unhashable: the safe loader refuses it below
                    continue
        return super().construct_mapping(node, deep)


def _read_yaml(path: Path) -> Any:
    if not path.is_file():
        raise ConfigError(f"{path}: " + ("a folder, not a config file" if path.is_dir()
                                         else "no such config file"))
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a UTF-8 text file (byte 0x{exc.object[exc.start]:02x} "
                          f"at offset {exc.start})") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot be read ({exc.strerror})") from None
    try:
        return yaml.load(text, Loader=UniqueKeyLoader)
    except _DuplicateKeyError as exc:
        where = "" if exc.line is None else f" (line {exc.line})"
        raise ConfigError(f"{path}: duplicate key {exc.key!r}{where}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({' '.join(str(exc).split())})") from exc
    except RecursionError:
        raise ConfigError(f"{path}: not valid YAML (nested too deeply)") from None


def _validate(model: type[_Model], data: Any, source: str) -> Any:
    if data is None:
        raise ConfigError(f"{source}: the config is empty; expected a mapping of keys")
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping of keys, got {type(data).__name__}")
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_format(source, exc)) from None
