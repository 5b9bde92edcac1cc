#!/usr/bin/python3
"""A foreign Modbus TCP server for cross-checking ModbusArm: Debian's python3-pymodbus (3.0)
serving an arm config's register map ([bus.modbus.registers] of a hw_configs/*.toml) with fixed
encoder counts, written apart from the C++ code on purpose: its own reading of the schema (per-joint
address lists, u16/i16/u32/i32/f32, word order, byte order within a register, scale and bias, the
status word's named bits with their polarity, the enable and fault-reset values).

The drive it models: `enabled` while the enable register holds its `on` value and there is no
fault; `ready` while there is no fault and no e-stop; SIGUSR1 raises a drive fault (latched until
the fault-reset value is written), SIGUSR2 toggles the e-stop. What the client writes (setpoints,
enable, heartbeat, watchdog time) stays in the holding registers for the test to read back.

    /usr/bin/python3 pymodbus_arm.py --config hw_configs/modbus_tcp_arm.toml --port 0 \
        --counts 1000,-2000,300000 --buttons 0x13

Prints one line, `pymodbus_arm: serving '<name>' on 127.0.0.1:<port>`, once it listens.
Needs Python 3.11 (tomllib) and pymodbus 3.0 (`apt-get install python3-pymodbus`).
"""

import argparse
import asyncio
import signal
import struct
import sys
import tomllib

try:
    import serial  # noqa: F401
    import serial_asyncio  # noqa: F401
except ModuleNotFoundError:
    # pymodbus.server imports pyserial for its serial server, which this TCP-only script never uses,
    # and python3-pymodbus only recommends python3-serial-asyncio: stand-ins keep the import working
    # on an install with --no-install-recommends.
    import types

    _serial = types.ModuleType("serial")
    _serial.serialutil = types.SimpleNamespace(SerialException=OSError)
    sys.modules.setdefault("serial", _serial)
    _serial_asyncio = types.ModuleType("serial_asyncio")
    _serial_asyncio.create_serial_connection = None
    sys.modules.setdefault("serial_asyncio", _serial_asyncio)

from pymodbus.datastore import ModbusSequentialDataBlock, ModbusServerContext, ModbusSlaveContext  # noqa: E402
from pymodbus.server.async_io import ModbusTcpServer  # noqa: E402

WIDTH = {"u16": 1, "i16": 1, "u32": 2, "i32": 2, "f32": 2}
PER_JOINT = ("encoder_counts", "current_command", "torque_command")


class Entry:
    """One entry of the map: its registers and how a value is coded in them."""

    def __init__(self, key, spec, defaults, joints):
        self.key = key
        self.table = spec["table"]
        self.kind = spec["type"]
        self.width = WIDTH[self.kind]
        self.high_first = spec.get("word_order", defaults["word_order"]) == "high_first"
        self.swap = spec.get("byte_order", defaults["byte_order"]) == "little"
        self.scale = float(spec.get("scale", 1.0))
        self.bias = float(spec.get("bias", 0.0))
        values = joints if key in PER_JOINT else 1
        a = spec["address"]
        self.addresses = list(a) if isinstance(a, list) else [a + i * self.width for i in range(values)]
        self.spec = spec

    def _words(self, bits):
        words = [bits & 0xFFFF] if self.width == 1 else [bits >> 16, bits & 0xFFFF]
        if self.width == 2 and not self.high_first:
            words.reverse()
        if self.swap:
            words = [((w & 0xFF) << 8) | (w >> 8) for w in words]
        return words

    def _bits(self, words):
        if self.swap:
            words = [((w & 0xFF) << 8) | (w >> 8) for w in words]
        if self.width == 2 and not self.high_first:
            words = list(reversed(words))
        return words[0] if self.width == 1 else (words[0] << 16) | words[1]

    def encode_raw(self, raw):
        """Registers of one raw value."""
        if self.kind == "f32":
            return self._words(struct.unpack(">I", struct.pack(">f", raw))[0])
        return self._words(int(round(raw)) & (0xFFFF if self.width == 1 else 0xFFFFFFFF))

    def decode_raw(self, words):
        bits = self._bits(words)
        if self.kind == "f32":
            return struct.unpack(">f", struct.pack(">I", bits))[0]
        if self.kind in ("i16", "i32") and bits >= 1 << (16 * self.width - 1):
            bits -= 1 << (16 * self.width)
        return bits

    def encode(self, physical):
        return self.encode_raw((physical - self.bias) / self.scale)


class Drive:
    """The registers and the drive behind them."""

    def __init__(self, config, counts, buttons, extra_status):
        regs = config["bus"]["modbus"]["registers"]
        defaults = {"word_order": regs.get("word_order", "high_first"), "byte_order": regs.get("byte_order", "big")}
        joints = len(config["joints"])
        self.entries = {k: Entry(k, v, defaults, joints) for k, v in regs.items() if isinstance(v, dict)}
        self.tables = {"input": {}, "holding": {}}
        self.fault = False
        self.estop = False
        self.extra_status = extra_status
        for j, c in enumerate(counts):
            self.put("encoder_counts", self.entries["encoder_counts"].encode(c), j)
        if "buttons" in self.entries:
            self.put("buttons", self.entries["buttons"].encode_raw(buttons))
        setpoint = "torque_command" if "torque_command" in self.entries else "current_command"
        for j in range(joints):
            self.put(setpoint, self.entries[setpoint].encode(0.0), j)
        if "enable" in self.entries:
            self.put("enable", self.entries["enable"].encode_raw(self.entries["enable"].spec["off"]))
        for key in ("heartbeat", "watchdog_timeout"):
            if key in self.entries:
                self.put(key, self.entries[key].encode_raw(0))
        self.update_status()

    def put(self, key, words, value=0):
        e = self.entries[key]
        for i, w in enumerate(words):
            self.tables[e.table][e.addresses[value] + i] = w

    def word(self, key):
        e = self.entries[key]
        return e.decode_raw([self.tables[e.table].get(e.addresses[0] + i, 0) for i in range(e.width)])

    def enabled(self):
        if "enable" not in self.entries:
            return not self.fault
        return self.word("enable") == self.entries["enable"].spec["on"] and not self.fault and not self.estop

    def update_status(self):
        if "status" not in self.entries:
            return
        bits = self.entries["status"].spec.get("bits", {})
        word = self.extra_status
        state = {"fault": self.fault, "estop": self.estop, "enabled": self.enabled(),
                 "ready": not self.fault and not self.estop, "comm_lost": False}
        for name, b in bits.items():
            bit, low = (b, False) if isinstance(b, int) else (b["bit"], b.get("active_low", False))
            if state[name] != low:
                word |= 1 << bit
        self.put("status", self.entries["status"].encode_raw(word))

    def written(self):
        """After a write: a fault reset clears the fault."""
        if "fault_reset" in self.entries and self.word("fault_reset") == self.entries["fault_reset"].spec["value"]:
            self.fault = False
        self.update_status()


class Block(ModbusSequentialDataBlock):
    """A table of the drive: reads see the status as it is now, writes reach the drive."""

    def __init__(self, drive, table):
        size = max(drive.tables[table].keys(), default=-1) + 1
        super().__init__(0, [drive.tables[table].get(a, 0) for a in range(max(size, 1))])
        self.drive = drive
        self.table = table

    def getValues(self, address, count=1):  # noqa: N802 (pymodbus' name)
        self.drive.update_status()
        for a, w in self.drive.tables[self.table].items():
            super().setValues(a, [w])
        return super().getValues(address, count)

    def setValues(self, address, values):  # noqa: N802
        super().setValues(address, values)
        for i, w in enumerate(values if isinstance(values, list) else [values]):
            self.drive.tables[self.table][address + i] = w
        self.drive.written()


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", required=True, help="arm TOML with a [bus.modbus] register map")
    parser.add_argument("--port", type=int, default=0, help="TCP port on 127.0.0.1 (0: ephemeral)")
    parser.add_argument("--counts", default="", help="encoder counts, one per joint, comma-separated (scale · raw + bias)")
    parser.add_argument("--status", type=lambda s: int(s, 0), default=0, help="bits OR'ed into the status word")
    parser.add_argument("--buttons", type=lambda s: int(s, 0), default=0, help="buttons register word")
    args = parser.parse_args()

    with open(args.config, "rb") as f:
        config = tomllib.load(f)
    joints = len(config["joints"])
    counts = [float(c) for c in args.counts.split(",")] if args.counts else [0.0] * joints
    if len(counts) != joints:
        sys.exit(f"pymodbus_arm: --counts needs {joints} values, found {len(counts)}")
    drive = Drive(config, counts, args.buttons, args.status)
    # zero_mode: request address N is register N (pymodbus otherwise adds one).
    slave = ModbusSlaveContext(ir=Block(drive, "input"), hr=Block(drive, "holding"), zero_mode=True)
    context = ModbusServerContext(slaves=slave, single=True)

    def raise_fault():
        drive.fault = True
        drive.update_status()

    def toggle_estop():
        drive.estop = not drive.estop
        drive.update_status()

    async def serve():
        loop = asyncio.get_running_loop()
        loop.add_signal_handler(signal.SIGUSR1, raise_fault)
        loop.add_signal_handler(signal.SIGUSR2, toggle_estop)
        server = ModbusTcpServer(context, address=("127.0.0.1", args.port), allow_reuse_address=True)
        task = asyncio.create_task(server.serve_forever())
        await server.serving
        port = server.server.sockets[0].getsockname()[1]
        print(f"pymodbus_arm: serving '{config['name']}' on 127.0.0.1:{port}", flush=True)
        await task

    asyncio.run(serve())


if __name__ == "__main__":
    main()
