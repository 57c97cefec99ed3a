"""The project's strict pydantic base and the one reading of a validation error: the configuration spine's checks.

:class:`KnownKeys` and :class:`Strict` are the bases of every configuration model (:mod:`flashnav.config`,
:mod:`flashnav.learn.hparams`, :mod:`flashnav.request`, the sweep schema): an unknown key is an error that names it
and lists the allowed names, and no number is inf or NaN. :func:`problems` and :func:`error_lines` turn a pydantic
error into one ``key.path: message (got value)`` line per problem, so that a bad input is named wherever it is read.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, ValidationError, model_validator
from pydantic_core import PydanticCustomError


class KnownKeys(BaseModel):
    """Base: unknown keys are errors that name the key and the allowed names (a misspelt key must not
    be silently ignored, and the message should say what was meant); no number is inf or NaN (a time step, radius or
    reward of inf or NaN once passed ``gt=0`` and unbounded fields, and failed later in a kernel's traceback or in a
    NaN action far from the key that caused it)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, data: Any) -> Any:
        # Checked here rather than by extra="forbid" alone so the message can list the allowed names.
        if isinstance(data, dict):
            for key in data:
                if key not in cls.model_fields:
                    raise PydanticCustomError("unknown_key", "unknown key; allowed: {allowed}",
                                              {"key": str(key), "allowed": ", ".join(sorted(cls.model_fields))})
        return data


class Strict(KnownKeys):
    """Base of frozen models: unknown keys are errors that list the allowed names."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


_TYPE_TAGS = {"str", "int", "float", "bool", "dict", "list", "none", "tuple"}


def _is_union_tag(part: str) -> bool:
    """A union member's tag in a pydantic error path (``str``, ``list[str]``, ``GeneratedMaps``), not a key."""
    return part in _TYPE_TAGS or "[" in part or part[:1].isupper()


def problems(exc: ValidationError) -> list[tuple[list[str], dict]]:
    """(key path, pydantic error item) per problem, the one home of how a validation error is read: an unknown
    key's name joins its path; where a value failed every member of a union (``maps``: a string, a list or
    generated maps) and one member said why in words, or failed inside one of its fields (the member the value was
    meant for: ``maps.count=0`` of generated maps), only that reason is kept, under the key's own path (not
    "maps.str: ..., maps.list[str]: ...")."""
    errors, out = exc.errors(), []

    def head(loc) -> tuple[str, ...] | None:  # the key path before the first union tag (None: no union)
        parts = [str(p) for p in loc]
        return next((tuple(parts[:k]) for k, p in enumerate(parts) if k and _is_union_tag(p)), None)

    def meant(e) -> bool:  # a reason in words, or an error inside a member's own field (deeper than its tag)
        h = head(e["loc"])
        return e["type"] == "value_error" or (h is not None and len(e["loc"]) > len(h) + 1)

    reasons = {head(e["loc"]) for e in errors if meant(e)} - {None}
    for item in errors:
        loc = [str(part) for part in item["loc"]]
        if head(item["loc"]) in reasons:
            if not meant(item):
                continue  # a union member the value was not meant for
            loc = [part for k, part in enumerate(loc) if not (k and _is_union_tag(part))]
        if item["type"] == "unknown_key":
            loc.append(str((item.get("ctx") or {}).get("key", "?")))
        out.append((loc, item))
    return out


def error_lines(exc: ValidationError, section: str | None = None) -> list[str]:
    """One ``key.path: message`` per problem of a pydantic error (:func:`problems`), with the value that failed
    a bound or a type; with ``section`` (``algo``, ``robot``) the path starts with it, and a problem of the section as
    a whole (a check across its keys) reads ``section: message``."""
    lines = []
    for loc, item in problems(exc):
        loc = ([section] if section else []) + loc
        got = ""
        if item["type"] != "unknown_key" and isinstance(item.get("input"), (int, float, str)) \
                and len(repr(item["input"])) <= 60:
            got = f" (got {item['input']!r})"  # a scalar that failed a bound or a type: say which value
        lines.append(f"{'.'.join(loc) or '<top>'}: {item['msg'].removeprefix('Value error, ')}{got}")
    return lines
