#!/usr/bin/python3
"""A foreign Modbus TCP server for cross-checking ModbusArm: Debian's python3-pymodbus (3.0)
serving an arm config's register map ([bus.modbus.registers] of a hw_configs/*.toml) with fixed
encoder counts, status and buttons. What the client writes (currents, control, heartbeat) stays in
the holding registers for the test to read back.

    /usr/bin/python3 pymodbus_arm.py --config hw_configs/modbus_tcp_arm.toml --port 0 \
        --counts 1000,-2000,300000 --status 2 --buttons 0x13

Prints one line, `pymodbus_arm: serving '<name>' on 127.0.0.1:<port>`, once it listens.
Needs Python 3.11 (tomllib) and pymodbus 3.0 (`apt-get install python3-pymodbus`).
"""

import argparse
import asyncio
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

WIDTH = {"u16": 1, "i16": 1, "u32": 2, "i32": 2}


def encode(value, kind, high_first):
    """Registers of one value of `kind` (two's complement, word order for 32-bit kinds)."""
    if WIDTH[kind] == 1:
        return [value & 0xFFFF]
    bits = value & 0xFFFFFFFF
    hi, lo = bits >> 16, bits & 0xFFFF
    return [hi, lo] if high_first else [lo, hi]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", required=True, help="arm TOML with a [bus.modbus] register map")
    parser.add_argument("--port", type=int, default=0, help="TCP port on 127.0.0.1 (0: ephemeral)")
    parser.add_argument("--counts", default="", help="encoder counts, one per joint, comma-separated")
    parser.add_argument("--status", type=lambda s: int(s, 0), default=0, help="status register word")
    parser.add_argument("--buttons", type=lambda s: int(s, 0), default=0, help="buttons register word")
    args = parser.parse_args()

    with open(args.config, "rb") as f:
        config = tomllib.load(f)
    regs = config["bus"]["modbus"]["registers"]
    high_first = regs.get("word_order", "high_first") == "high_first"
    joints = len(config["joints"])
    counts = [int(c, 0) for c in args.counts.split(",")] if args.counts else [0] * joints
    if len(counts) != joints:
        sys.exit(f"pymodbus_arm: --counts needs {joints} values, found {len(counts)}")

    # Fill both tables from the map; each spans from register 0 to the last mapped one.
    tables = {"input": {}, "holding": {}}

    def put(entry, values):
        spec = regs.get(entry)
        if spec is None:
            return
        addr = spec["address"]
        for v in values:
            for r in encode(v, spec["type"], high_first):
                tables[spec["table"]][addr] = r
                addr += 1

    put("encoder_counts", counts)
    put("status", [args.status])
    put("buttons", [args.buttons])
    put("current_command", [0] * joints)
    put("control", [0])
    put("heartbeat", [0])

    def block(table):
        size = max(tables[table].keys(), default=-1) + 1
        values = [tables[table].get(a, 0) for a in range(max(size, 1))]
        return ModbusSequentialDataBlock(0, values)

    # zero_mode: request address N is register N (pymodbus otherwise adds one).
    slave = ModbusSlaveContext(ir=block("input"), hr=block("holding"), zero_mode=True)
    context = ModbusServerContext(slaves=slave, single=True)

    async def serve():
        server = ModbusTcpServer(context, address=("127.0.0.1", args.port), allow_reuse_address=True)
        task = asyncio.create_task(server.serve_forever())
        await server.serving
        port = server.server.sockets[0].getsockname()[1]
        print(f"pymodbus_arm: serving '{config['name']}' on 127.0.0.1:{port}", flush=True)
        await task

    asyncio.run(serve())


if __name__ == "__main__":
    main()
