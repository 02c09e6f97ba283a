"""The generated layout tables of ``firmware/PROTOCOL.md``."""

from __future__ import annotations

import re

from gripper_env.hardware.layouts.description import (
    WIRE_TYPES,
    Description,
    LayoutError,
    Message,
    field_offsets,
)

__all__ = ["render_markdown", "update_markdown"]


def _md_rows(desc: Description, m: Message) -> list[str]:
    rows = ["| offset | type | field | unit, rule, meaning |", "|---|---|---|---|"]
    for f, o in zip(m.fields, field_offsets(m.fields), strict=True):
        rows.append(f"| {o} | {f.type} | `{f.name}` | {f.doc} |")
    a = m.array
    if a is not None:
        if a.of in WIRE_TYPES:
            rows.append(f"| {m.size} | {a.of}[k] | `{a.name}` | {a.doc} |")
        else:
            size = desc.array_size(a)
            flds = desc.structs[a.of][1]
            for f, o in zip(flds, field_offsets(flds), strict=True):
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
