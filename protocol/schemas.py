"""JSON Schemas (draft 2020-12) of the messages, derived from their bounded field types.

The shipped files, `protocol/schemas/<Type>.schema.json`, describe the JSON object
of each message for other implementations; a test checks that they equal what
this module generates, so they cannot drift from `protocol/messages.py`.

    python -m protocol.schemas --write     # regenerate the files after changing a message
    python -m protocol.schemas --check     # exit 1 if a file differs from the messages
"""
from __future__ import annotations

import argparse
import json
import sys
import types
import typing
from pathlib import Path
from typing import Any, Literal, get_args, get_origin

from .bounds import MAX_DEPTH, Cell, MaxLen, Pattern, Range, bound, unwrap
from .codec import json_limit
from .messages import MESSAGE_TYPES, SCHEMA_VERSION, Message, wire_fields

DRAFT = "https://json-schema.org/draft/2020-12/schema"
SCHEMA_DIR = Path(__file__).with_name("schemas")
NAMED = {Cell: "cell"}  # shapes written once under $defs: a cell appears up to three times a message


def type_schema(tp: Any, defs: dict[str, Any]) -> dict[str, Any]:
    """The schema of one field type, with the bounds its annotation carries; named shapes go to `defs`."""
    name = NAMED.get(tp)
    if name is None:
        return _inline(tp, defs)
    if name not in defs:
        defs[name] = _inline(tp, defs)
    return {"$ref": f"#/$defs/{name}"}


def _inline(tp: Any, defs: dict[str, Any]) -> dict[str, Any]:
    base, meta = unwrap(tp)
    origin = get_origin(base)
    if base is Any:
        return {}
    if base is bool:
        return {"type": "boolean"}
    if base is int or base is float:
        r = bound(meta, Range)
        return {"type": "integer" if base is int else "number",
                "exclusiveMinimum" if r.open_lo else "minimum": r.lo, "maximum": r.hi}
    if base is str:
        out: dict[str, Any] = {"type": "string", "maxLength": bound(meta, MaxLen).n}
        pattern = bound(meta, Pattern)
        if pattern is not None:
            out["pattern"] = f"^(?:{pattern.regex})$"  # JSON Schema patterns are not anchored
        return out
    if origin is Literal:
        return {"enum": list(get_args(base))}
    if origin is tuple:
        items = [type_schema(a, defs) for a in get_args(base)]
        return {"type": "array", "prefixItems": items, "items": False, "minItems": len(items), "maxItems": len(items)}
    if origin is list:
        return {"type": "array", "items": type_schema(get_args(base)[0], defs), "maxItems": bound(meta, MaxLen).n}
    if origin is dict:
        key, value = get_args(base)
        return {"type": "object", "propertyNames": type_schema(key, defs),
                "additionalProperties": type_schema(value, defs), "maxProperties": bound(meta, MaxLen).n}
    if origin in (typing.Union, types.UnionType):
        return {"anyOf": [type_schema(a, defs) for a in get_args(base)]}
    raise TypeError(f"no JSON Schema for {tp}")


def _blob(cls: type[Message]) -> Any:
    return next((f for f in wire_fields(cls) if unwrap(f.type)[0] is bytes), None)


def message_schema(cls: type[Message]) -> dict[str, Any]:
    name = cls.__name__
    doc = cls.__doc__ or ""
    written = "" if doc.startswith(name + "(") else " ".join(doc.split())  # dataclass makes one up when none is written
    notes = [written,
             f"A UTF-8 JSON object of at most {json_limit(cls)} bytes, nested at most {MAX_DEPTH} levels deep;"
             " receivers ignore properties they do not know."]
    blob = _blob(cls)
    if blob is not None:
        notes.append(f"On the wire the JSON is followed by a NUL byte and `{blob.name}`, at most "
                     f"{bound(unwrap(blob.type)[1], MaxLen).n} bytes, which this schema does not cover.")
    properties: dict[str, Any] = {"type": {"const": name}, "v": {"const": SCHEMA_VERSION}}
    required = ["type", "v"]
    defs: dict[str, Any] = {}
    for f in wire_fields(cls):
        if f is blob:
            continue
        properties[f.name] = type_schema(f.type, defs)
        if f.required:
            required.append(f.name)
    schema = {"$schema": DRAFT, "$id": f"urn:uav-robots:protocol:v{SCHEMA_VERSION}:{name}", "title": name,
              "description": " ".join(n for n in notes if n), "type": "object", "properties": properties,
              "required": required}
    if defs:
        schema["$defs"] = defs
    return schema


def schema_files() -> dict[str, str]:
    """File name -> the text it must hold, for every message type."""
    return {f"{name}.schema.json": json.dumps(message_schema(cls), indent=2) + "\n"
            for name, cls in MESSAGE_TYPES.items()}


def stale_files(directory: Path = SCHEMA_DIR) -> list[str]:
    """Names of the files that are missing, differ from the generator, or belong to no message."""
    want = schema_files()
    have = {p.name for p in directory.glob("*.schema.json")} if directory.is_dir() else set()
    wrong = [n for n, text in want.items() if n not in have or (directory / n).read_text(encoding="utf-8") != text]
    return sorted(wrong + list(have - set(want)))


def write(directory: Path = SCHEMA_DIR) -> list[str]:
    directory.mkdir(parents=True, exist_ok=True)
    want = schema_files()
    for old in directory.glob("*.schema.json"):
        if old.name not in want:
            old.unlink()
    for n, text in want.items():
        (directory / n).write_text(text, encoding="utf-8")
    return sorted(want)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m protocol.schemas", description=__doc__.splitlines()[0])
    p.add_argument("--dir", type=Path, default=SCHEMA_DIR, help=f"where the files are (default {SCHEMA_DIR})")
    action = p.add_mutually_exclusive_group(required=True)
    action.add_argument("--write", action="store_true", help="regenerate the schema files")
    action.add_argument("--check", action="store_true", help="exit 1 if a file is stale")
    a = p.parse_args(argv)
    if a.write:
        print(f"wrote {len(write(a.dir))} schemas to {a.dir}")
        return 0
    stale = stale_files(a.dir)
    if stale:
        print(f"stale schemas in {a.dir}: {', '.join(stale)} (run python -m protocol.schemas --write)", file=sys.stderr)
        return 1
    print(f"{len(MESSAGE_TYPES)} schemas in {a.dir} match the messages")
    return 0


if __name__ == "__main__":
    sys.exit(main())
