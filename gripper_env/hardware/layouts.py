"""The protocol's message layouts from their one description, ``firmware/protocol.toml``.

The description lists the constants, enumerations and messages of the serial protocol (ids,
fields, wire types, units). From it this module

* writes the firmware's ``firmware/gripper/gripper_messages.h`` (message structs with their
  little-endian codecs, the enums, the constants), which the sketch and the host harness compile;
* writes the layout tables of ``firmware/PROTOCOL.md`` (between its ``GENERATED`` markers);
* checks the Python twin, :mod:`gripper_env.hardware.protocol`, against it: type ids, field names
  and order, wire types, enum values, constants.

``python -m gripper_env.hardware.layouts`` regenerates both files; ``--check`` only reports
what is out of date (exit status 1), which the test suite runs.

Examples
--------
>>> desc = load_description()
>>> desc.messages["CONFIGURE"].size
50
"""

from __future__ import annotations

import argparse
import re
import sys
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from gripper_env.files import write_atomic

__all__ = [
    "DESCRIPTION",
    "Description",
    "check_python",
    "load_description",
    "main",
    "render_header",
    "render_markdown",
]

FIRMWARE = Path(__file__).resolve().parents[2] / "firmware"
DESCRIPTION = FIRMWARE / "protocol.toml"
HEADER = FIRMWARE / "gripper" / "gripper_messages.h"
PROTOCOL_MD = FIRMWARE / "PROTOCOL.md"

# wire type -> (C++ type, struct format char, size, put/get suffix)
WIRE_TYPES = {
    "u8": ("uint8_t", "B", 1, "u8"),
    "i8": ("int8_t", "b", 1, "i8"),
    "u16": ("uint16_t", "H", 2, "u16"),
    "i16": ("int16_t", "h", 2, "i16"),
    "u32": ("uint32_t", "I", 4, "u32"),
    "f32": ("float", "f", 4, "f32"),
}
_CODEC_NAMES = {"b", "len", "e", "c", "k", "TYPE", "SIZE", "HEADER", "ENTRY_SIZE"}
CONST_TYPES = {"u8": "uint8_t", "u16": "uint16_t", "i16": "int16_t", "size": "size_t"}


class LayoutError(ValueError):
    """The description is malformed; the message names the key."""


@dataclass(frozen=True)
class Field:
    """One wire field: ``name``, wire ``type`` (u8 ... f32) and its ``doc`` (unit, rule)."""

    name: str
    type: str
    doc: str = ""


@dataclass(frozen=True)
class Array:
    """Entries after a message's fixed fields: ``of`` a wire type or a struct name, ``min`` to
    ``max`` of them, counted by the field ``count`` or implied by the payload length."""

    name: str
    of: str
    min: int
    max: str | int
    count: str | None = None
    doc: str = ""


@dataclass(frozen=True)
class Message:
    """A message layout."""

    key: str
    id: int
    cpp: str
    python: str
    fields: tuple[Field, ...]
    array: Array | None = None
    field_enum: str | None = None

    @property
    def to_device(self) -> bool:
        """Host -> device (ids below 0x80)."""
        return self.id < 0x80

    @property
    def size(self) -> int:
        """Bytes of the fixed fields (the whole payload if there is no array)."""
        return sum(WIRE_TYPES[f.type][2] for f in self.fields)

    @property
    def format(self) -> str:
        """:mod:`struct` format characters of the fixed fields."""
        return "".join(WIRE_TYPES[f.type][1] for f in self.fields)


@dataclass(frozen=True)
class Member:
    name: str
    value: int
    doc: str = ""
    detail: str = ""


@dataclass(frozen=True)
class Enum:
    name: str
    python: str
    prefix: str
    doc: str
    members: tuple[Member, ...]
    bits: bool = False


@dataclass(frozen=True)
class Description:
    """Everything in ``protocol.toml``."""

    constants: dict[str, tuple[int, str, str]]  # name -> (value, type, doc)
    enums: dict[str, Enum]
    structs: dict[str, tuple[str, tuple[Field, ...]]]  # name -> (python name, fields)
    messages: dict[str, Message]

    def array_size(self, array: Array) -> int:
        """Bytes of one array entry."""
        if array.of in WIRE_TYPES:
            return WIRE_TYPES[array.of][2]
        return sum(WIRE_TYPES[f.type][2] for f in self.structs[array.of][1])

    def array_max(self, array: Array) -> int:
        return array.max if isinstance(array.max, int) else self.constants[array.max][0]


# ---- loading -------------------------------------------------------------------------------------


def _fields(items: Any, where: str) -> tuple[Field, ...]:
    if not isinstance(items, list):
        raise LayoutError(f"{where}: 'fields' must be a list")
    out = []
    for k, item in enumerate(items):
        try:
            f = Field(**item)
        except TypeError as exc:
            raise LayoutError(f"{where}.fields[{k}]: {exc}") from None
        if f.type not in WIRE_TYPES:
            raise LayoutError(
                f"{where}.fields[{k}] ({f.name}): unknown wire type {f.type!r}; "
                f"use one of {', '.join(WIRE_TYPES)}"
            )
        out.append(f)
    names = [f.name for f in out]
    clash = set(names) & _CODEC_NAMES
    if clash:
        raise LayoutError(f"{where}: field names {sorted(clash)} are the generated codecs' locals")
    if len(set(names)) != len(names):
        raise LayoutError(f"{where}: duplicate field names in {names}")
    return tuple(out)


def load_description(path: str | Path = DESCRIPTION) -> Description:
    """Read and check ``protocol.toml``.

    Raises
    ------
    LayoutError
        A malformed entry, naming the file and the key.
    """
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise LayoutError(f"{path}: {exc}") from None
    try:
        constants = {
            name: (int(c["value"]), str(c["type"]), str(c.get("doc", "")))
            for name, c in raw["constants"].items()
        }
        for name, (_value, typ, _doc) in constants.items():
            if typ not in CONST_TYPES:
                raise LayoutError(
                    f"{path}: constants.{name}: type must be one of {list(CONST_TYPES)}"
                )
        enums = {
            name: Enum(
                name,
                e["python"],
                e["prefix"],
                e.get("doc", ""),
                tuple(Member(**m) for m in e["members"]),
                bool(e.get("bits", False)),
            )
            for name, e in raw["enums"].items()
        }
        structs = {
            name: (s["python"], _fields(s["fields"], f"{path}: structs.{name}"))
            for name, s in raw["structs"].items()
        }
        messages = {}
        for key, m in raw["messages"].items():
            where = f"{path}: messages.{key}"
            array = Array(**m["array"]) if "array" in m else None
            if array is not None and array.of not in WIRE_TYPES and array.of not in structs:
                raise LayoutError(f"{where}.array: 'of' names no wire type or struct: {array.of}")
            messages[key] = Message(
                key,
                int(m["id"]),
                m["cpp"],
                m["python"],
                _fields(m["fields"], where),
                array,
                m.get("field_enum"),
            )
    except KeyError as exc:
        raise LayoutError(f"{path}: missing key {exc}") from None
    except TypeError as exc:
        raise LayoutError(f"{path}: {exc}") from None
    ids = [m.id for m in messages.values()]
    if len(set(ids)) != len(ids):
        raise LayoutError(f"{path}: duplicate message ids {sorted(ids)}")
    return Description(constants, enums, structs, messages)


# ---- the C++ header ------------------------------------------------------------------------------


def _comment(doc: str) -> str:
    return f" // {doc}" if doc else ""


def _cpp_struct_fields(flds: Sequence[Field], indent: str = "    ") -> list[str]:
    return [f"{indent}{WIRE_TYPES[f.type][0]} {f.name};{_comment(f.doc)}" for f in flds]


def _put(f: Field, ptr: str, offset: int | str, value: str) -> str:
    at = f"{ptr} + {offset}" if offset != 0 else ptr
    if f.type == "u8":
        return f"{ptr}[{offset}] = {value};"
    if f.type == "i8":
        return f"{ptr}[{offset}] = (uint8_t){value};"
    return f"put_{f.type}({at}, {value});"


def _get(f: Field, ptr: str, offset: int | str) -> str:
    at = f"{ptr} + {offset}" if offset != 0 else ptr
    if f.type == "u8":
        return f"{ptr}[{offset}]"
    if f.type == "i8":
        return f"(int8_t){ptr}[{offset}]"
    return f"get_{f.type}({at})"


def _offsets(flds: Sequence[Field]) -> list[int]:
    out, at = [], 0
    for f in flds:
        out.append(at)
        at += WIRE_TYPES[f.type][2]
    return out


def _message_cpp(desc: Description, m: Message) -> list[str]:
    lines = [f"// {m.key} (0x{m.id:02X}, {'host -> device' if m.to_device else 'device -> host'})"]
    lines.append(f"struct {m.cpp} {{")
    offs = _offsets(m.fields)
    a = m.array
    if a is None:
        lines.append(f"    enum {{ TYPE = MSG_{m.key}, SIZE = {m.size} }};")
        lines += _cpp_struct_fields(m.fields)
        if not m.fields:
            lines.append("    size_t encode(uint8_t*) const { return SIZE; }")
            lines.append("    bool decode(const uint8_t*, size_t len) { return len == SIZE; }")
            lines.append("};")
            return lines
        lines.append("    size_t encode(uint8_t* b) const {")
        lines += [f"        {_put(f, 'b', o, f.name)}" for f, o in zip(m.fields, offs, strict=True)]
        lines += [
            "        return SIZE;",
            "    }",
            "    bool decode(const uint8_t* b, size_t len) {",
        ]
        lines.append("        if (len != SIZE) return false;")
        lines += [
            f"        {f.name} = {_get(f, 'b', o)};" for f, o in zip(m.fields, offs, strict=True)
        ]
        lines += ["        return true;", "    }", "};"]
        return lines
    entry = desc.array_size(a)
    struct_fields = () if a.of in WIRE_TYPES else desc.structs[a.of][1]
    lines.append(f"    enum {{ TYPE = MSG_{m.key}, HEADER = {m.size}, ENTRY_SIZE = {entry} }};")
    lines += _cpp_struct_fields(m.fields)
    count = a.count or "count"
    if a.count is None:
        lines.append("    uint8_t count; // entries in this message (from the payload length)")
    elem = WIRE_TYPES[a.of][0] if a.of in WIRE_TYPES else a.of
    lines.append(f"    {elem} {a.name}[{a.max}];{_comment(a.doc)}")
    # encode
    lines.append("    size_t encode(uint8_t* b) const {")
    lines += [f"        {_put(f, 'b', o, f.name)}" for f, o in zip(m.fields, offs, strict=True)]
    lines.append(f"        for (uint8_t k = 0; k < {count}; ++k) {{")
    lines.append("            uint8_t* e = b + HEADER + ENTRY_SIZE * k;")
    if struct_fields:
        for f, o in zip(struct_fields, _offsets(struct_fields), strict=True):
            lines.append(f"            {_put(f, 'e', o, f'{a.name}[k].{f.name}')}")
    else:
        lines.append(f"            {_put(Field('x', a.of), 'e', 0, f'{a.name}[k]')}")
    lines += ["        }", f"        return HEADER + ENTRY_SIZE * (size_t){count};", "    }"]
    # decode
    lines.append("    bool decode(const uint8_t* b, size_t len) {")
    if a.count is not None:
        idx = next(k for k, f in enumerate(m.fields) if f.name == a.count)
        lines.append("        if (len < HEADER) return false;")
        lines.append(f"        uint8_t c = {_get(m.fields[idx], 'b', offs[idx])};")
        lines.append(
            f"        if (c < {a.min} || c > {a.max} || len != HEADER + ENTRY_SIZE * (size_t)c) "
            "return false;"
        )
        for f, o in zip(m.fields, offs, strict=True):
            value = "c" if f.name == a.count else _get(f, "b", o)
            lines.append(f"        {f.name} = {value};")
    else:
        lines.append(
            f"        if (len < HEADER + ENTRY_SIZE * {a.min} || (len - HEADER) % ENTRY_SIZE != 0) "
            "return false;"
        )
        lines.append(f"        if ((len - HEADER) / ENTRY_SIZE > {a.max}) return false;")
        lines += [
            f"        {f.name} = {_get(f, 'b', o)};" for f, o in zip(m.fields, offs, strict=True)
        ]
        lines.append("        count = (uint8_t)((len - HEADER) / ENTRY_SIZE);")
    lines.append(f"        for (uint8_t k = 0; k < {count}; ++k) {{")
    lines.append("            const uint8_t* e = b + HEADER + ENTRY_SIZE * k;")
    if struct_fields:
        for f, o in zip(struct_fields, _offsets(struct_fields), strict=True):
            lines.append(f"            {a.name}[k].{f.name} = {_get(f, 'e', o)};")
    else:
        lines.append(f"            {a.name}[k] = {_get(Field('x', a.of), 'e', 0)};")
    lines += ["        }", "        return true;", "    }", "};"]
    return lines


def render_header(desc: Description) -> str:
    """The text of ``gripper_messages.h``."""
    out = [
        "// gripper_messages.h - GENERATED from firmware/protocol.toml by",
        "// `python -m gripper_env.hardware.layouts`. Do not edit: change the description and",
        "// regenerate (tests/hardware/test_hw_layouts.py fails while this file is out of date).",
        "//",
        "// The protocol's constants, enums and messages. Each message has TYPE, its fixed SIZE",
        "// (or HEADER and ENTRY_SIZE), encode(out) -> payload length, and decode(in, len) -> bool",
        "// (false for a payload length the type does not allow). Fields are packed little-endian,",
        "// field by field (gripper_wire.h), never by struct memcpy.",
        "",
        "#ifndef GRIPPER_MESSAGES_H",
        "#define GRIPPER_MESSAGES_H",
        "",
        "#include <stddef.h>",
        "#include <stdint.h>",
        "",
        '#include "gripper_wire.h"',
        "",
        "namespace gripper {",
        "",
    ]
    for name, (value, typ, doc) in desc.constants.items():
        out.append(f"const {CONST_TYPES[typ]} {name} = {value};{_comment(doc)}")
    out += [
        "",
        "// Message type ids. Host -> device below 0x80, device -> host from 0x80.",
        "enum MessageType {",
    ]
    msgs = list(desc.messages.values())
    for k, m in enumerate(msgs):
        out.append(f"    MSG_{m.key} = 0x{m.id:02X}{',' if k + 1 < len(msgs) else ''}")
    out.append("};")
    for e in desc.enums.values():
        out += ["", f"// {e.doc}" if e.doc else "", f"enum {e.name} {{"]
        for k, mem in enumerate(e.members):
            value = f"0x{mem.value:02X}" if e.bits else str(mem.value)
            sep = "," if k + 1 < len(e.members) else ""
            doc = mem.doc or mem.detail
            out.append(f"    {e.prefix}{mem.name} = {value}{sep}{_comment(doc)}")
        out.append("};")
    for m in msgs:
        if m.field_enum:
            out += ["", f"// Field indices of {m.key} (ERROR.detail of BAD_VALUE), in wire order."]
            out.append(f"enum {m.cpp}Field {{")
            for k, f in enumerate(m.fields):
                sep = "," if k + 1 < len(m.fields) else ""
                out.append(f"    {m.field_enum}{f.name.upper()} = {k}{sep}")
            out.append("};")
    for name, (_python, flds) in desc.structs.items():
        out += ["", f"struct {name} {{", *_cpp_struct_fields(flds), "};"]
    for m in msgs:
        out += ["", *_message_cpp(desc, m)]
    out += ["", "} // namespace gripper", "", "#endif // GRIPPER_MESSAGES_H", ""]
    return "\n".join(line for line in out if line is not None)


# ---- PROTOCOL.md tables --------------------------------------------------------------------------


def _md_rows(desc: Description, m: Message) -> list[str]:
    rows = ["| offset | type | field | unit, rule, meaning |", "|---|---|---|---|"]
    for f, o in zip(m.fields, _offsets(m.fields), strict=True):
        rows.append(f"| {o} | {f.type} | `{f.name}` | {f.doc} |")
    a = m.array
    if a is not None:
        if a.of in WIRE_TYPES:
            rows.append(f"| {m.size} | {a.of}[k] | `{a.name}` | {a.doc} |")
        else:
            size = desc.array_size(a)
            flds = desc.structs[a.of][1]
            for f, o in zip(flds, _offsets(flds), strict=True):
                rows.append(
                    f"| {m.size + o} + {size}j | {f.type} | `{a.name}[j].{f.name}` | {f.doc} |"
                )
    return rows


def _md_heading(desc: Description, m: Message) -> str:
    way = "host -> device" if m.to_device else "device -> host"
    a = m.array
    if a is None:
        size = f"{m.size} byte{'s' if m.size != 1 else ''}"
    else:
        entry = desc.array_size(a)
        size = f"{m.size} + {entry}k bytes, {a.min} <= k <= {desc.array_max(a)}"
    return f"### 0x{m.id:02X} {m.key} ({way}, {size})"


def render_markdown(desc: Description) -> dict[str, str]:
    """The generated blocks of ``PROTOCOL.md``, by marker name."""
    blocks = {}
    for m in desc.messages.values():
        lines = [_md_heading(desc, m), ""]
        lines += _md_rows(desc, m) if (m.fields or m.array) else ["Empty payload."]
        blocks[f"message {m.key}"] = "\n".join(lines)
    codes = desc.enums["ErrorCode"]
    lines = ["| code | name | detail |", "|---|---|---|"]
    lines += [f"| {mem.value} | {mem.name} | {mem.detail} |" for mem in codes.members]
    blocks["error codes"] = "\n".join(lines)
    return blocks


_BLOCK = re.compile(
    r"<!-- BEGIN GENERATED (?P<name>[^>]+?) -->\n.*?<!-- END GENERATED (?P=name) -->", re.S
)


def update_markdown(text: str, blocks: dict[str, str]) -> str:
    """Replace each ``<!-- BEGIN GENERATED name -->`` block of ``text`` with ``blocks[name]``.

    Raises
    ------
    LayoutError
        A block named in ``blocks`` has no markers in ``text``, or the text has an unknown one.
    """
    found = set()

    def replace(match: re.Match[str]) -> str:
        name = match["name"]
        if name not in blocks:
            raise LayoutError(f"PROTOCOL.md has a generated block {name!r} the description lacks")
        found.add(name)
        return f"<!-- BEGIN GENERATED {name} -->\n{blocks[name]}\n<!-- END GENERATED {name} -->"

    out = _BLOCK.sub(replace, text)
    missing = sorted(set(blocks) - found)
    if missing:
        raise LayoutError(f"PROTOCOL.md lacks the generated blocks {missing}: add their markers")
    return out


# ---- the Python twin -----------------------------------------------------------------------------


def check_python(desc: Description) -> list[str]:
    """Differences between :mod:`gripper_env.hardware.protocol` and the description."""
    from gripper_env.hardware import protocol as proto

    problems = []
    for name, (value, _typ, _doc) in desc.constants.items():
        if getattr(proto, name, None) != value:
            problems.append(f"protocol.{name} = {getattr(proto, name, None)!r}, expected {value}")
    for e in desc.enums.values():
        cls = getattr(proto, e.python, None)
        got = {k: v for k, v in vars(cls).items() if not k.startswith("_")} if cls else {}
        want = {mem.name: mem.value for mem in e.members}
        if got != want:
            problems.append(f"protocol.{e.python} is {got}, expected {want}")
    for pyname, flds in desc.structs.values():
        cls = getattr(proto, pyname)
        names = [f.name for f in fields(cls)]
        if names != [f.name for f in flds]:
            problems.append(f"protocol.{pyname} fields {names}, expected {[f.name for f in flds]}")
    sample_format = "<" + "".join(WIRE_TYPES[f.type][1] for f in desc.structs["TelemetrySample"][1])
    if proto._SAMPLE.format != sample_format:
        problems.append(f"protocol._SAMPLE is {proto._SAMPLE.format!r}, expected {sample_format!r}")
    if set(proto.MESSAGE_TYPES) != {m.id for m in desc.messages.values()}:
        problems.append(f"protocol.MESSAGE_TYPES ids {sorted(proto.MESSAGE_TYPES)} differ")
    for m in desc.messages.values():
        cls = getattr(proto, m.python, None)
        if cls is None:
            problems.append(f"protocol has no class {m.python} for {m.key}")
            continue
        if cls.TYPE != m.id:
            problems.append(f"protocol.{m.python}.TYPE = 0x{cls.TYPE:02x}, expected 0x{m.id:02x}")
        names = [f.name for f in fields(cls)]
        if m.array is None:
            want = [f.name for f in m.fields]
            if getattr(cls, "_FORMAT", None) != m.format:
                problems.append(
                    f"protocol.{m.python}._FORMAT = {getattr(cls, '_FORMAT', None)!r}, "
                    f"expected {m.format!r}"
                )
        else:
            want = [f.name for f in m.fields if f.name != m.array.count] + [m.array.name]
        if names != want:
            problems.append(f"protocol.{m.python} fields {names}, expected {want}")
    header = "<" + desc.messages["TELEMETRY"].format
    if proto._TELEMETRY_HEADER.format != header:
        problems.append(f"protocol._TELEMETRY_HEADER is {proto._TELEMETRY_HEADER.format!r}")
    return problems


# ---- command line --------------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m gripper_env.hardware.layouts``."""
    parser = argparse.ArgumentParser(
        prog="python -m gripper_env.hardware.layouts",
        description="Generate firmware/gripper/gripper_messages.h and the layout tables of "
        "firmware/PROTOCOL.md from firmware/protocol.toml, and check protocol.py against it.",
    )
    parser.add_argument(
        "--check",
        action="store_true",
        help="write nothing; exit 1 if a generated file is out of date or protocol.py differs",
    )
    args = parser.parse_args(argv)
    try:
        desc = load_description()
        outputs = {
            HEADER: render_header(desc),
            PROTOCOL_MD: update_markdown(PROTOCOL_MD.read_text(), render_markdown(desc)),
        }
    except LayoutError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    stale = [p for p, text in outputs.items() if not p.exists() or p.read_text() != text]
    problems = check_python(desc)
    if args.check:
        for p in stale:
            print(f"{p.relative_to(FIRMWARE.parent)} is out of date: run {parser.prog}")
        for line in problems:
            print(line)
        return 1 if stale or problems else 0
    for p in stale:
        write_atomic(p, outputs[p])
        print(f"wrote {p.relative_to(FIRMWARE.parent)}")
    for line in problems:
        print(f"protocol.py: {line}", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
