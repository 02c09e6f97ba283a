// gripper_core.h - all hardware-independent logic of the gripper firmware, in four units:
//
//   protocol  gripper_wire.h (packing, CRC-16, COBS), gripper_messages.h (constants, enums and
//             message codecs, generated from firmware/protocol.toml), gripper_protocol.h (frames
//             and the stream decoder)
//   pid       gripper_pid.h (the same equations as gripper_env.pid.pid_update)
//   safety    gripper_safety.h (jaw clamp, ADC <-> angle, servo pulse limits, watchdog)
//   device    gripper_device.h (the protocol and mode state machine the sketch drives)
//
// Shared by the Arduino Mega 2560 sketch (gripper.ino, avr-gcc 5.4, -std=gnu++11, 32-bit double)
// and the host test harness (firmware/host/harness.cpp, g++ -std=c++17): plain C++11, no Arduino
// headers, no C++ standard library, no heap, no exceptions. These files, in the sketch folder,
// are the one copy both builds compile (arduino-cli only compiles what is in the sketch folder).

#ifndef GRIPPER_CORE_H
#define GRIPPER_CORE_H

#include "gripper_device.h"
#include "gripper_messages.h"
#include "gripper_pid.h"
#include "gripper_protocol.h"
#include "gripper_safety.h"
#include "gripper_wire.h"

#endif // GRIPPER_CORE_H
