"""Settings as YAML: any tree of config dataclasses written out with a comment per field, and
read back with every key and value checked.

A config dataclass documents each field with a one-line comment at the end of the field's
line (longer reasons stay in comment lines above it); ``field_docs`` reads those comments from
the source, so the YAML a user sees says what the code says. Nested dataclasses become nested
sections. Values are numbers, booleans, strings, ``null`` and lists (tuples).
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import inspect
import io
import math
import os
import textwrap
import tokenize
import types
import typing
from typing import Any

import yaml

from mapfilter.errors import MapfilterError
from mapfilter.io.yamlio import compose_yaml, construct, read_yaml_text

# what a setting unknown to this release may be: one an older release removed (each named there)
REMOVED_SETTINGS_NOTE = "settings removed by a release: docs/changelog.md"
_MAX_INT = 2**63 - 1  # a whole number setting ends up in an int64 (numpy, numba)

__all__ = ["REMOVED_SETTINGS_NOTE", "field_docs", "settings_from_yaml", "settings_to_dict", "settings_to_yaml",
           "replace_setting"]


@functools.cache
def field_docs(cls: type) -> dict[str, str]:
    """{field name: the comment at the end of its line} of a dataclass (from its source), or its
    field's ``metadata["doc"]`` (a dataclass made at run time has no source)."""
    given = {f.name: f.metadata["doc"] for f in dataclasses.fields(cls) if "doc" in f.metadata}
    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return given
    comments = {tok.start[0]: tok.string.lstrip("#").strip()
                for tok in tokenize.generate_tokens(io.StringIO(source).readline) if tok.type == tokenize.COMMENT}
    body = ast.parse(source).body[0]
    docs = {}
    for node in getattr(body, "body", []):
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            comment = comments.get(node.end_lineno)
            if comment:
                docs[node.target.id] = comment
    return {**docs, **given}


def _settings_fields(cls: type) -> list[dataclasses.Field]:
    return [f for f in dataclasses.fields(cls) if f.init]


def settings_to_dict(config: Any) -> dict:
    """A config dataclass as plain data (nested dicts, lists for tuples)."""
    out = {}
    for f in _settings_fields(type(config)):
        value = getattr(config, f.name)
        if dataclasses.is_dataclass(value):
            out[f.name] = settings_to_dict(value)
        elif isinstance(value, tuple):
            out[f.name] = list(value)
        else:
            out[f.name] = value
    return out


def settings_to_yaml(config: Any, header: str = "") -> str:
    """The config as YAML, each field with its one-line comment (``field_docs``)."""
    lines = [f"# {line}" if line else "#" for line in header.splitlines()]
    _yaml_lines(config, 0, lines)
    return "\n".join(lines) + "\n"


def _scalar(value: Any) -> str:
    text = yaml.safe_dump(value, default_flow_style=True, width=1_000_000).strip()
    return text.removesuffix("\n...").strip()


def _yaml_lines(config: Any, indent: int, lines: list[str]) -> None:
    docs = field_docs(type(config))
    pad = "  " * indent
    for f in _settings_fields(type(config)):
        value = getattr(config, f.name)
        doc = docs.get(f.name, "")
        if dataclasses.is_dataclass(value):
            lines.append(f"{pad}{f.name}:" + (f"  # {doc}" if doc else ""))
            _yaml_lines(value, indent + 1, lines)
        else:
            plain = list(value) if isinstance(value, tuple) else value
            lines.append(f"{pad}{f.name}: {_scalar(plain)}" + (f"  # {doc}" if doc else ""))


def settings_from_yaml(cls: type, text_or_path: str | os.PathLike, base: Any = None) -> Any:
    """A ``cls`` from YAML text or a YAML file: the keys given replace those of ``base`` (default:
    ``cls()``), the rest keep their values. Unknown keys and values of the wrong type are a
    ``MapfilterError`` naming the file, the line and the setting (and where a setting an older
    release removed is listed: ``REMOVED_SETTINGS_NOTE``)."""
    where, text = _source(text_or_path)
    node = compose_yaml(text, where)  # size, alias and duplicate-key limits of every YAML mapfilter reads
    base = base if base is not None else cls()
    if node is None:
        return base
    return _apply(base, node, where, "")


def _source(text_or_path: str | os.PathLike) -> tuple[str, str]:
    if isinstance(text_or_path, os.PathLike) or ("\n" not in str(text_or_path) and
                                                  str(text_or_path).endswith((".yaml", ".yml"))):
        return str(text_or_path), read_yaml_text(text_or_path, "a config file")
    return "the config", str(text_or_path)


def _apply(config: Any, node: yaml.Node, where: str, prefix: str) -> Any:
    cls = type(config)
    if not isinstance(node, yaml.MappingNode):
        raise MapfilterError(f"{where} line {node.start_mark.line + 1}: {prefix.rstrip('.') or 'the config'} must "
                             f"be a mapping of settings")
    fields = {f.name: f for f in _settings_fields(cls)}
    hints = typing.get_type_hints(cls)
    changes = {}
    for key_node, value_node in node.value:
        key = key_node.value
        name = f"{prefix}{key}"
        line = key_node.start_mark.line + 1
        if key not in fields:
            known = ", ".join(fields)
            raise MapfilterError(f"{where} line {line}: unknown setting {name!r} (known here: {known}; "
                                 f"{REMOVED_SETTINGS_NOTE})")
        current = getattr(config, key)
        if dataclasses.is_dataclass(current):
            changes[key] = _apply(current, value_node, where, f"{name}.")
        else:
            value = construct(value_node)
            changes[key] = _coerce(value, hints[key], f"{where} line {line}: {name}")
    try:
        return dataclasses.replace(config, **changes)
    except MapfilterError as exc:
        raise MapfilterError(f"{where}: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise MapfilterError(f"{where}: {prefix.rstrip('.') or 'the config'}: {exc}") from None


def _coerce(value: Any, hint: Any, what: str) -> Any:
    """``value`` as the type ``hint`` says (int, float, bool, str, None, tuples), else an error."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        options = typing.get_args(hint)
        if value is None and type(None) in options:
            return None
        errors = []
        for option in options:
            if option is type(None):
                continue
            try:
                return _coerce(value, option, what)
            except MapfilterError as exc:
                errors.append(str(exc))
        raise MapfilterError(errors[0] if errors else f"{what}: got {value!r}")
    if origin is tuple:
        args = typing.get_args(hint)
        if not isinstance(value, list):
            raise MapfilterError(f"{what}: expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], what) for v in value)
        if len(value) != len(args):
            raise MapfilterError(f"{what}: expected {len(args)} values, got {len(value)}")
        return tuple(_coerce(v, a, what) for v, a in zip(value, args))
    if hint is bool:
        if not isinstance(value, bool):
            raise MapfilterError(f"{what}: expected true or false, got {value!r}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise MapfilterError(f"{what}: expected a whole number, got {value!r}")
        if abs(value) > _MAX_INT:
            raise MapfilterError(f"{what}: {str(value)[:20]}... is beyond any count or seed (at most {_MAX_INT})")
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise MapfilterError(f"{what}: expected a finite number, got {value!r}")
        return float(value)
    if hint is str:
        if not isinstance(value, str):
            raise MapfilterError(f"{what}: expected text, got {value!r}")
        return value
    raise MapfilterError(f"{what}: cannot read a value of type {hint}")


def replace_setting(config: Any, dotted: str, value: Any) -> Any:
    """``config`` with the setting at ``dotted`` (e.g. ``"filter.n_particles"``) replaced."""
    head, _, rest = dotted.partition(".")
    if rest:
        return dataclasses.replace(config, **{head: replace_setting(getattr(config, head), rest, value)})
    return dataclasses.replace(config, **{head: value})
