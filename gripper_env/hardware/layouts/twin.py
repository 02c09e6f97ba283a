"""The check of the Python twin, :mod:`gripper_env.hardware.protocol`, against the description."""

from __future__ import annotations

from dataclasses import fields

from gripper_env.hardware.layouts.description import WIRE_TYPES, Description

__all__ = ["check_python"]


def check_python(desc: Description) -> list[str]:
    """Differences between :mod:`gripper_env.hardware.protocol` and the description."""
    from gripper_env.hardware import protocol as proto
    from gripper_env.hardware.protocol import reports

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
    if reports.SAMPLE_STRUCT.format != sample_format:
        problems.append(
            f"protocol.reports.SAMPLE_STRUCT is {reports.SAMPLE_STRUCT.format!r}, "
            f"expected {sample_format!r}"
        )
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
            want_names = [f.name for f in m.fields]
            if getattr(cls, "_FORMAT", None) != m.format:
                problems.append(
                    f"protocol.{m.python}._FORMAT = {getattr(cls, '_FORMAT', None)!r}, "
                    f"expected {m.format!r}"
                )
        else:
            want_names = [f.name for f in m.fields if f.name != m.array.count] + [m.array.name]
        if names != want_names:
            problems.append(f"protocol.{m.python} fields {names}, expected {want_names}")
    header = "<" + desc.messages["TELEMETRY"].format
    header_format = reports.TELEMETRY_HEADER_STRUCT.format
    if header_format != header:
        problems.append(
            f"protocol.reports.TELEMETRY_HEADER_STRUCT is {header_format!r}, expected {header!r}"
        )
    return problems
