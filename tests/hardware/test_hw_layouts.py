"""The message layouts come from one description (firmware/protocol.toml): the generated firmware
header and PROTOCOL.md tables are current, and the Python twin matches it."""

from __future__ import annotations

import dataclasses

import pytest

from gripper_env.hardware import layouts
from gripper_env.hardware import protocol as proto


def test_generated_files_are_current_and_python_matches(capsys) -> None:
    status = layouts.main(["--check"])
    assert status == 0, capsys.readouterr().out


def test_the_description_gives_the_wire_sizes() -> None:
    desc = layouts.load_description()
    sizes = {m.key: m.size for m in desc.messages.values()}
    # PROTOCOL.md's sizes, counted by hand from the field tables
    assert sizes == {
        "HELLO": 2, "CONFIGURE": 69, "SET_MODE": 1, "SETPOINT": 4, "PROFILE_CHUNK": 4,
        "HEARTBEAT": 4, "ESTOP": 0, "INFO": 29, "TELEMETRY": 7, "STATUS": 34, "ERROR": 5,
    }  # fmt: skip
    for m in desc.messages.values():
        cls = proto.MESSAGE_TYPES[m.id]
        if m.array is None:
            assert cls._STRUCT.size == m.size  # type: ignore[attr-defined]


def test_a_changed_layout_is_caught() -> None:
    desc = layouts.load_description()
    configure = desc.messages["CONFIGURE"]
    fields = list(configure.fields)
    fields[9] = dataclasses.replace(fields[9], type="u32")  # adc_at_lo widened on one side only
    changed = dataclasses.replace(configure, fields=tuple(fields))
    other = dataclasses.replace(desc, messages={**desc.messages, "CONFIGURE": changed})
    assert any("Configure._FORMAT" in p for p in layouts.check_python(other))
    assert layouts.render_header(other) != layouts.HEADER.read_text()
    swapped = dataclasses.replace(desc.enums["Fault"], members=desc.enums["Fault"].members[::-1])
    swapped = dataclasses.replace(swapped, members=tuple(
        dataclasses.replace(m, value=1 << k) for k, m in enumerate(swapped.members)
    ))  # fmt: skip
    other = dataclasses.replace(desc, enums={**desc.enums, "Fault": swapped})
    assert any("protocol.Fault" in p for p in layouts.check_python(other))


def test_bad_descriptions_name_the_key(tmp_path) -> None:
    text = layouts.DESCRIPTION.read_text()
    bad = tmp_path / "protocol.toml"
    bad.write_text(text.replace('{ name = "token", type = "u32"', '{ name = "token", type = "u31"'))
    with pytest.raises(layouts.LayoutError, match=r"messages.HEARTBEAT.fields\[0\] \(token\)"):
        layouts.load_description(bad)
    bad.write_text(text.replace('{ name = "token", type = "u32"', '{ name = "len", type = "u32"'))
    with pytest.raises(layouts.LayoutError, match="codecs' locals"):
        layouts.load_description(bad)
