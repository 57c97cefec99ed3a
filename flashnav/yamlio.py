"""YAML in and out, and dotted ``key=value`` overrides, for every FlashNav configuration file.

YAML is always loaded safely (:class:`UniqueKeyLoader`, a ``yaml.SafeLoader`` that also refuses a repeated
key), and every error names its source. The models these files are validated against are in
:mod:`flashnav.config`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel


class DuplicateKeyError(yaml.YAMLError):
    """A mapping names the same key twice (plain YAML keeps the last one silently)."""


class UniqueKeyLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses duplicate mapping keys: in a sweep or a config a repeated key
    is almost always an edit gone wrong, and the silent last-one-wins would run something else."""

    def construct_mapping(self, node, deep=False):
        first: dict[Any, yaml.Node] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # '<<: *base' overrides by design
                continue
            key = self.construct_object(key_node, deep=True)
            try:
                seen = first.setdefault(key, key_node)
            except TypeError:  # an unhashable key: the base class raises its own clear error
                continue
            if seen is not key_node:
                raise DuplicateKeyError(f"duplicate key {key!r} at line {key_node.start_mark.line + 1} "
                                        f"(first at line {seen.start_mark.line + 1})")
        return super().construct_mapping(node, deep)


def yaml_error_line(exc: yaml.YAMLError) -> str:
    """A YAML error as one line (PyYAML's own text spans several, with a caret drawing)."""
    if isinstance(exc, yaml.MarkedYAMLError) and exc.problem:
        mark = exc.problem_mark
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        return f"{exc.problem}{where}"
    return " ".join(str(exc).split())


def parse_yaml(text: str, source: str = "<string>") -> Any:
    """YAML text -> Python data with :class:`UniqueKeyLoader`; a ValueError names ``source``."""
    try:
        return yaml.load(text, Loader=UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as exc:
        raise ValueError(f"{source}: not valid YAML: {yaml_error_line(exc)}") from None


def load_yaml(path: str | Path) -> Any:
    """Load YAML safely (a SafeLoader that refuses duplicate keys); a clear error names the file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ValueError(f"{path}: is a folder, not a YAML file") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not a UTF-8 text file ({exc.reason} at byte {exc.start})") from None
    return parse_yaml(text, str(path))


def dump_yaml(data: Any, path: str | Path) -> None:
    with open(path, "w", encoding="utf-8") as f:
        yaml.safe_dump(data, f, sort_keys=False)


# ---- dotted keys: the one setter behind every override path ---------------------------------------


def parse_assignment(item: str, what: str = "override") -> tuple[str, Any]:
    """``"algo.batch_size=512"`` -> ``("algo.batch_size", 512)``: the value is read as YAML, safely."""
    key, sep, raw = item.partition("=")
    key = key.strip()
    if not sep or not key:
        raise ValueError(f"{what} {item!r} is not key=value")
    try:
        return key, yaml.load(raw, Loader=UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as exc:
        raise ValueError(f"{what} {item!r}: the value is not valid YAML ({yaml_error_line(exc)})") from None


def set_dotted(data: dict, dotted: str | list[str], value: Any, *, known: Any = None, create: bool = False,
               what: str = "override", other_sections: tuple[str, ...] = ()) -> None:
    """Set ``data["a"]["b"]["c"] = value`` for ``dotted = "a.b.c"`` (or the parts ``["a", "b", "c"]``,
    where a part may itself hold dots: a key of a map of dotted keys), in place.

    ``known``: the names allowed at the leaf's level when it is not in ``data`` yet (a set of names,
    or a pydantic model class whose fields are allowed at the top level); ``create``: make missing
    sections instead of failing. An unknown name is a ValueError that names the key and suggests
    the closest allowed names; ``other_sections``: top-level section names that the caller routes
    elsewhere (``algo``, ``robot``), offered in that message. Every override path (``flashnav train
    key=value``, ``--config``, sweep ``--set``, preset and hyperparameter overrides) goes through here.
    """
    import difflib

    parts = dotted.split(".") if isinstance(dotted, str) else list(dotted)
    dotted = ".".join(parts)
    *parents, leaf = parts
    if not all(parents) or not leaf:
        raise ValueError(f"{what} {dotted!r}: empty name in the dotted key")
    node = data
    for i, part in enumerate(parents):
        child = node.get(part)
        if child is None and create:
            _check_section(part, parents[:i], known, what, dotted, other_sections if i == 0 else ())
            child = node[part] = {}
        if not isinstance(child, dict):
            where = ".".join(parents[: i + 1])
            if child is not None:
                raise ValueError(f"{what} {dotted!r}: {where!r} is not a section (it holds {child!r})")
            sections = sorted(k for k, v in node.items() if isinstance(v, dict))
            close = difflib.get_close_matches(part, sections, n=3)
            hint = f"; did you mean {', '.join(close)}?" if close else (
                f"; sections: {', '.join(sections)}" if sections else "")
            raise ValueError(f"{what} {dotted!r}: no section {where!r}{hint}")
        node = child
    allowed = set(node)
    if isinstance(known, type) and issubclass(known, BaseModel):
        allowed |= _fields_at(known, parents)
    elif known is not None:
        allowed |= set(known)
    if known is not None and leaf not in allowed:
        close = difflib.get_close_matches(leaf, sorted(allowed), n=3)
        hint = f"; did you mean {', '.join(close)}?" if close else f"; known: {', '.join(sorted(allowed))}"
        raise ValueError(f"{what} {dotted!r}: unknown key {leaf!r}{hint}")
    node[leaf] = value


def _check_section(part: str, path: list[str], known: Any, what: str, dotted: str, others: tuple[str, ...]) -> None:
    """Before ``set_dotted`` creates section ``part`` below ``path``: where ``known`` is a model that
    names the fields at that level, ``part`` must be one of those that hold a section (a sub-model)."""
    import difflib

    if not (isinstance(known, type) and issubclass(known, BaseModel)):
        return
    fields = _fields_at(known, path)
    if not fields or part in fields:
        return
    where = ".".join([*path, part])
    sections = sorted({f for f in fields if _fields_at(known, [*path, f])} | set(others)) or sorted(fields)
    close = difflib.get_close_matches(part, sorted(fields | set(others)), n=3)
    hint = f"; did you mean {', '.join(close)}?" if close else f"; sections here: {', '.join(sections)}"
    raise ValueError(f"{what} {dotted!r}: no section {where!r}{hint}")


def _fields_at(model: type[BaseModel], path: list[str]) -> set[str]:
    """Field names of the sub-model reached from ``model`` along ``path`` (empty if none is). A field that is a
    union (``maps``: a name, a list or generated maps) reaches the model among its members."""
    import typing

    for part in path:
        field = model.model_fields.get(part)
        sub = getattr(field, "annotation", None)
        if not (isinstance(sub, type) and issubclass(sub, BaseModel)):
            sub = next((m for m in typing.get_args(sub) if isinstance(m, type) and issubclass(m, BaseModel)), None)
        if sub is None:
            return set()
        model = sub
    return set(model.model_fields)


def flatten_dotted(data: dict, prefix: str = "") -> dict[str, Any]:
    """Nested dicts -> ``{"a.b.c": value}`` (the dotted keys :func:`set_dotted` takes; lists kept whole)."""
    out: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, dict):
            out.update(flatten_dotted(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def deep_merge(base: dict, top: dict) -> dict:
    """A new dict: ``top`` over ``base``, section by section (lists and values are replaced whole)."""
    out = dict(base)
    for key, value in top.items():
        out[key] = deep_merge(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out
