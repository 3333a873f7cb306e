"""The one YAML reader of mapfilter: every map, building, config, edits or connector file.

Files are other people's, so the reader bounds what a file can ask for: its size
(``MAX_YAML_BYTES``), and the nodes its aliases stand for (``MAX_ALIAS_NODES``: a "billion
laughs" file of a few hundred bytes whose anchors expand to 10^9 nodes is refused while it is
composed, before anything is built from it). A key given twice in one mapping is an error
naming the file and both lines (PyYAML keeps the last one silently). The text must be UTF-8
(a UTF-8 or UTF-16 byte-order mark is read); anything else is one line that says which byte
on which line is not, and a file that is not text at all (NUL bytes, an image's signature) is
called what it is.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

from mapfilter.errors import MapfilterError

__all__ = ["MAX_ALIAS_NODES", "MAX_YAML_BYTES", "compose_yaml", "construct", "load_yaml", "read_yaml_text"]

MAX_YAML_BYTES = 4 << 20  # 4 MiB: a map YAML is a few hundred bytes, a config a few kB
MAX_ALIAS_NODES = 100_000  # nodes reached through aliases, counted as often as they are reached
_MAX_DEPTH = 200  # nesting of collections
_IMAGE_SIGNATURES = (b"\x89PNG", b"\xff\xd8\xff", b"GIF8", b"II*\x00", b"MM\x00*", b"BM", b"P5", b"P6")

_Loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def read_yaml_text(path: str | os.PathLike, what: str = "a YAML file", max_bytes: int = MAX_YAML_BYTES) -> str:
    """The text of a YAML file, refused in one line naming the file when it is missing, larger
    than ``max_bytes``, not a file, or not UTF-8 text."""
    path = Path(path)
    try:
        with path.open("rb") as handle:
            if not os.path.isfile(path) and not _is_regular(handle):
                raise MapfilterError(f"{what} must be a file", path)
            data = handle.read(max_bytes + 1)
    except FileNotFoundError:
        raise MapfilterError("file not found", path) from None
    except IsADirectoryError:
        raise MapfilterError(f"is a directory, not {what}", path) from None
    except OSError as exc:
        raise MapfilterError(f"cannot read {what} ({exc.strerror or exc})", path) from None
    if len(data) > max_bytes:
        raise MapfilterError(f"{what} larger than {max_bytes >> 20} MiB: not one mapfilter reads", path)
    return decode_text(data, path, what)


def _is_regular(handle) -> bool:
    import stat

    return stat.S_ISREG(os.fstat(handle.fileno()).st_mode)


def decode_text(data: bytes, path: str | os.PathLike | None, what: str) -> str:
    """``data`` as text: UTF-8 (a byte-order mark is dropped) or UTF-16 with a byte-order mark;
    else one line saying what the bytes are."""
    if data.startswith((b"\xff\xfe", b"\xfe\xff")):
        try:
            return data.decode("utf-16")
        except UnicodeDecodeError:
            raise MapfilterError("starts as UTF-16 text but is not: save it as UTF-8", path) from None
    if data.startswith(_IMAGE_SIGNATURES) and b"\0" in data[:4096] or data.startswith(b"\x89PNG\r\n"):
        raise MapfilterError(f"not {what} (a text file) but an image: make a map from a floor plan image with "
                             "`mapfilter map prepare PLAN.png --out MAP.yaml`", path)
    if b"\0" in data:
        if data[1:2] == b"\0" or data[0:1] == b"\0":
            raise MapfilterError("looks like UTF-16 text without a byte-order mark: save it as UTF-8", path)
        raise MapfilterError(f"not {what} (a text file) but binary data", path)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise MapfilterError(f"byte 0x{data[exc.start]:02x} is not UTF-8 (a Latin-1 or Windows-1252 "
                             "character?): save the file as UTF-8", path, line) from None


def compose_yaml(text: str, where: str | os.PathLike | None) -> yaml.Node | None:
    """The node graph of one YAML document, checked: syntax, aliases within ``MAX_ALIAS_NODES``,
    nesting, no key twice in a mapping. ``where`` names the file in errors."""
    loader = _Loader(text)
    try:
        node = loader.get_single_node()
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or "malformed YAML"
        raise MapfilterError(f"not valid YAML: {problem}", where, None if mark is None else mark.line + 1) from None
    except RecursionError:
        raise MapfilterError(f"malformed YAML: nested more than {_MAX_DEPTH} levels", where) from None
    finally:
        loader.dispose()
    if node is not None:
        _check_graph(node, where)
    return node


def construct(node: yaml.Node | None) -> Any:
    """Python data of a checked node (``compose_yaml``): dicts, lists, strings, numbers, None."""
    if node is None:
        return None
    constructor = yaml.constructor.SafeConstructor()
    try:
        return constructor.construct_document(node)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise MapfilterError(f"malformed YAML: {getattr(exc, 'problem', None) or exc}", None if mark is None
                             else mark.name, None if mark is None else mark.line + 1) from None


def load_yaml(source: str | os.PathLike, what: str = "a YAML file", max_bytes: int = MAX_YAML_BYTES) -> Any:
    """The data of a YAML (or JSON) file, read within the limits of this module."""
    text = read_yaml_text(source, what, max_bytes)
    return construct(compose_yaml(text, source))


def _check_graph(root: yaml.Node, where) -> None:
    """Aliases (a node reached a second time) within ``MAX_ALIAS_NODES``, counting each subtree as
    often as it is reached; recursive aliases, deep nesting and duplicate keys refused."""
    sizes: dict[int, int] = {}  # id(node) -> nodes in its expanded subtree
    on_path: set[int] = set()
    reached: set[int] = set()
    alias_nodes = 0

    def size(node: yaml.Node, depth: int) -> int:
        nonlocal alias_nodes
        key = id(node)
        if key in on_path:
            raise MapfilterError("malformed YAML: an alias refers to a node that contains it", where,
                                 node.start_mark.line + 1)
        if key in sizes:  # reached again through an alias
            alias_nodes += sizes[key]
            if alias_nodes > MAX_ALIAS_NODES:
                raise MapfilterError(f"its aliases stand for more than {MAX_ALIAS_NODES} nodes (an alias bomb?)",
                                     where, node.start_mark.line + 1)
            return sizes[key]
        if depth > _MAX_DEPTH:
            raise MapfilterError(f"malformed YAML: nested more than {_MAX_DEPTH} levels", where,
                                 node.start_mark.line + 1)
        on_path.add(key)
        total = 1
        if isinstance(node, yaml.SequenceNode):
            for child in node.value:
                total += size(child, depth + 1)
        elif isinstance(node, yaml.MappingNode):
            _check_duplicate_keys(node, where)
            for key_node, value_node in node.value:
                total += size(key_node, depth + 1) + size(value_node, depth + 1)
        on_path.discard(key)
        reached.add(key)
        sizes[key] = total
        return total

    size(root, 0)


def _check_duplicate_keys(node: yaml.MappingNode, where) -> None:
    seen: dict[tuple[str, str], int] = {}
    for key_node, _ in node.value:
        if not isinstance(key_node, yaml.ScalarNode) or key_node.tag == "tag:yaml.org,2002:merge":
            continue
        line = key_node.start_mark.line + 1
        ident = (key_node.tag, key_node.value)
        if ident in seen:
            raise MapfilterError(f"key {key_node.value!r} given twice (lines {seen[ident]} and {line}): "
                                 "remove one", where, line)
        seen[ident] = line


def path_in_yaml(yaml_path: Path, name: Any) -> Path:
    """The file a YAML file names (``image: plan.png``): relative to the YAML's folder unless
    absolute; a name that cannot be resolved (a loop of symbolic links) is one line naming the YAML."""
    candidate = Path(str(name))
    try:
        return candidate if candidate.is_absolute() else (yaml_path.parent / candidate).resolve()
    except (RuntimeError, OSError) as exc:  # a symbolic link loop (RuntimeError before Python 3.13)
        raise MapfilterError(f"{str(name)[:200]!r} cannot be found: {exc}", yaml_path) from None


def path_for_yaml(path: str | os.PathLike, folder: Path) -> str:
    """How a YAML file in ``folder`` names ``path``: relative to the folder."""
    return os.path.relpath(Path(path).resolve(), folder.resolve())
