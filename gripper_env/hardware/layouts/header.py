"""The firmware's message header, ``firmware/gripper/gripper_messages.h``, from the description."""

from __future__ import annotations

from collections.abc import Sequence

from gripper_env.hardware.layouts.description import (
    CONST_TYPES,
    WIRE_TYPES,
    Description,
    Field,
    Message,
    field_offsets,
)

__all__ = ["render_header"]


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


def _message_cpp(desc: Description, m: Message) -> list[str]:
    lines = [f"// {m.key} (0x{m.id:02X}, {'host -> device' if m.to_device else 'device -> host'})"]
    lines.append(f"struct {m.cpp} {{")
    offs = field_offsets(m.fields)
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
        for f, o in zip(struct_fields, field_offsets(struct_fields), strict=True):
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
        for f, o in zip(struct_fields, field_offsets(struct_fields), strict=True):
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
            number = f"0x{mem.value:02X}" if e.bits else str(mem.value)
            sep = "," if k + 1 < len(e.members) else ""
            doc = mem.doc or mem.detail
            out.append(f"    {e.prefix}{mem.name} = {number}{sep}{_comment(doc)}")
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
