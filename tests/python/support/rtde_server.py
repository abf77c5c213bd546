"""A stand-in UR controller: an RTDE server (protocol 2 and 1) that serves the rows of a recording.

Runs as its own process (``ur-rtde`` holds the GIL while it negotiates, so a server thread in the
same interpreter would starve)::

    python rtde_server.py --port 0 --recording rows.csv [--rate-hz 500 | --fast]
        [--drop-after N] [--damage KIND --damage-after N] [--restart-after N]
        [--dashboard-port 0 --model UR10 --serial 20235500001]

The recording is in ``ur_rtde``'s CSV form: a header of RTDE names (vectors as ``name_0``…),
one row per data package. The server knows exactly the recording's variables and answers
``NOT_FOUND`` for any other. Each ``--port`` is one controller with its own play head; every
client of a controller streams from where the controller's clock is (the row after the last one
sent, plus ``--skip-on-drop`` rows after a dropped link: the controller's clock ran on while the
link was down). It prints ``listening <port> …`` on stdout once every port accepts.

With ``--dashboard-port`` (one per ``--port``, 0: any free one) each controller also runs a
dashboard server, as a controller does on port 29999: a greeting line, then one answer line per
command line (``get robot model``, ``get serial number``, ``PolyscopeVersion``, ``quit``; anything
else is not understood), answering ``--model`` and ``--serial``. Its ports are printed as
``dashboard <port> …`` before the ``listening`` line.

Faults, each counted per controller:
- ``--drop-after N``: closes a streaming link after N rows (``--drop-times`` links, default 1).
- ``--damage KIND --damage-after N``: after N rows on a link, sends one damaged frame
  (``--damage-times``, default 1): ``size`` (a data package one byte short), ``recipe`` (another
  recipe id), ``header`` (a header whose size is below 3), ``type`` (an unknown package type),
  ``garbage`` (64 random bytes).
- ``--restart-after N``: after N rows of the controller, drops every link and restarts its
  clock: the rows that follow are served with timestamps counted from 0.

Binds 127.0.0.1 only. Standard library only.
"""

from __future__ import annotations

import argparse
import csv
import os
import re
import socket
import struct
import sys
import threading
import time

# Output variables and their types, from UR's RTDE guide (the ones a recording may carry).
TYPES = {
    "timestamp": "DOUBLE",
    "target_q": "VECTOR6D",
    "target_qd": "VECTOR6D",
    "target_qdd": "VECTOR6D",
    "target_current": "VECTOR6D",
    "target_moment": "VECTOR6D",
    "actual_q": "VECTOR6D",
    "actual_qd": "VECTOR6D",
    "actual_current": "VECTOR6D",
    "joint_control_output": "VECTOR6D",
    "actual_TCP_pose": "VECTOR6D",
    "tcp_offset": "VECTOR6D",
    "actual_TCP_speed": "VECTOR6D",
    "actual_TCP_force": "VECTOR6D",
    "target_TCP_pose": "VECTOR6D",
    "target_TCP_speed": "VECTOR6D",
    "actual_digital_input_bits": "UINT64",
    "joint_temperatures": "VECTOR6D",
    "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32",
    "safety_status_bits": "UINT32",
    "actual_tool_accelerometer": "VECTOR3D",
    "speed_scaling": "DOUBLE",
    "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE",
    "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE",
    "actual_joint_voltage": "VECTOR6D",
    "actual_digital_output_bits": "UINT64",
    "runtime_state": "UINT32",
    "robot_status_bits": "UINT32",
    "payload": "DOUBLE",
    "payload_cog": "VECTOR3D",
    "standard_analog_input0": "DOUBLE",
    "standard_analog_input1": "DOUBLE",
}
# struct format and width of each type.
FORMATS = {
    "DOUBLE": ("d", 1),
    "VECTOR6D": ("6d", 6),
    "VECTOR3D": ("3d", 3),
    "VECTOR6INT32": ("6i", 6),
    "VECTOR6UINT32": ("6I", 6),
    "INT32": ("i", 1),
    "UINT32": ("I", 1),
    "UINT64": ("Q", 1),
    "UINT8": ("B", 1),
    "BOOL": ("?", 1),
}
CONTROLLER_VERSION = (5, 21, 0, 9)


def package(kind: bytes, payload: bytes = b"") -> bytes:
    return struct.pack(">HB", 3 + len(payload), kind[0]) + payload


def read_recording(path: str) -> tuple[dict[str, tuple[str, list[int]]], list[list[str]]]:
    """The recording's variables (name → type and column indexes) and its rows as text."""
    with open(path, newline="") as handle:
        rows = list(csv.reader(handle))
    header, rows = rows[0], rows[1:]
    variables: dict[str, tuple[str, list[int]]] = {}
    for index, column in enumerate(header):
        match = re.fullmatch(r"(.+)_(\d)", column)
        name = match.group(1) if match and match.group(1) in TYPES else column
        if name not in TYPES:
            raise SystemExit(f"{path}: column '{column}' is no RTDE output variable this server knows")
        variables.setdefault(name, (TYPES[name], []))[1].append(index)
    for name, (kind, columns) in variables.items():
        if len(columns) != FORMATS[kind][1]:
            raise SystemExit(f"{path}: {name} is {kind} but has {len(columns)} columns")
    return variables, rows


def value(kind: str, cells: list[str]):
    if kind in ("DOUBLE", "VECTOR6D", "VECTOR3D"):
        return [float(cell) for cell in cells]
    if kind == "BOOL":
        return [cells[0].strip().lower() in ("1", "true")]
    return [int(cell) for cell in cells]


class Controller:
    """One controller: its recording, play head, clock and fault budget."""

    def __init__(self, args, variables, rows):
        self.args = args
        self.variables = variables
        self.rows = rows
        self.lock = threading.Lock()
        self.resume_row = 0
        self.drops_left = args.drop_times if args.drop_after is not None else 0
        self.damages_left = args.damage_times if args.damage else 0
        self.restart_at = args.restart_after
        self.clock_base_s = 0.0
        self.links: set[socket.socket] = set()

    def serve(self, listener: socket.socket) -> None:
        while True:
            try:
                connection, _ = listener.accept()
            except OSError:
                return
            connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            threading.Thread(target=Link(self, connection).run, daemon=True).start()


class Link:
    """One client's connection: the exchange, then its data packages."""

    def __init__(self, controller: Controller, connection: socket.socket):
        self.controller = controller
        self.connection = connection
        self.version = 2
        self.recipe: list[tuple[str, str, list[int]]] | None = None
        self.recipe_id = 0
        self.streaming = threading.Event()
        self.closed = threading.Event()
        self.send_lock = threading.Lock()

    def send(self, data: bytes) -> None:
        with self.send_lock:
            self.connection.sendall(data)

    def close(self) -> None:
        self.closed.set()
        try:
            self.connection.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.connection.close()

    def run(self) -> None:
        with self.controller.lock:
            self.controller.links.add(self.connection)
        buffer = b""
        try:
            while not self.closed.is_set():
                chunk = self.connection.recv(65536)
                if not chunk:
                    break
                buffer += chunk
                while len(buffer) >= 3:
                    size, kind = struct.unpack_from(">HB", buffer)
                    if size < 3:
                        return
                    if len(buffer) < size:
                        break
                    payload, buffer = buffer[3:size], buffer[size:]
                    self.on_package(chr(kind), payload)
        except OSError:
            pass
        finally:
            self.streaming.clear()
            self.closed.set()
            with self.controller.lock:
                self.controller.links.discard(self.connection)
            self.connection.close()

    def on_package(self, kind: str, payload: bytes) -> None:
        if kind == "V":
            (version,) = struct.unpack(">H", payload)
            accepted = version in (1, 2) and not (version == 2 and self.controller.args.protocol == 1)
            if accepted:
                self.version = version
            self.send(package(b"V", bytes([accepted])))
        elif kind == "v":
            self.send(package(b"v", struct.pack(">IIII", *CONTROLLER_VERSION)))
        elif kind == "O":
            names = payload[8:] if self.version == 2 else payload
            # ur_rtde ends the list with a comma; a controller takes that as no variable.
            names = [name for name in names.decode().split(",") if name]
            types = []
            recipe = []
            for name in names:
                known = self.controller.variables.get(name)
                types.append(known[0] if known else "NOT_FOUND")
                if known:
                    recipe.append((name, known[0], known[1]))
            complete = len(recipe) == len(names)
            self.recipe = recipe if complete else None
            self.recipe_id = 1
            answer = ",".join(types).encode()
            self.send(package(b"O", (bytes([self.recipe_id]) + answer) if self.version == 2 else answer))
        elif kind == "I":
            # No inputs: every input variable is unknown here.
            count = len(payload.decode().split(","))
            self.send(package(b"I", bytes([0]) + ",".join(["NOT_FOUND"] * count).encode()))
        elif kind == "S":
            accepted = self.recipe is not None
            self.send(package(b"S", bytes([accepted])))
            if accepted and not self.streaming.is_set():
                self.streaming.set()
                threading.Thread(target=self.stream, daemon=True).start()
        elif kind == "P":
            self.streaming.clear()
            self.send(package(b"P", bytes([1])))
        elif kind == "M":
            pass
        else:
            self.send(package(b"M", bytes([12]) + b"unknown type" + bytes([4]) + b"test" + bytes([1])))

    def data(self, row: list[str], timestamp_s: float) -> bytes:
        out = bytearray([self.recipe_id]) if self.version == 2 else bytearray()
        for name, kind, columns in self.recipe:
            values = value(kind, [row[c] for c in columns])
            if name == "timestamp":
                values = [timestamp_s]
            out += struct.pack(">" + FORMATS[kind][0], *values)
        return package(b"U", bytes(out))

    def damaged(self, kind: str, good: bytes) -> bytes:
        if kind == "size":
            return package(b"U", good[3:-1])
        if kind == "recipe":
            return package(b"U", bytes([self.recipe_id + 1]) + good[4:])
        if kind == "header":
            return b"\x00\x01U"
        if kind == "type":
            return package(b"Z", b"\x00" * 8)
        return os.urandom(64)

    def stream(self) -> None:
        controller, args = self.controller, self.controller.args
        period_s = None if args.fast else 1.0 / args.rate_hz
        sent = 0
        next_s = time.monotonic()
        timestamp_column = controller.variables["timestamp"][1][0]
        try:
            while self.streaming.is_set() and not self.closed.is_set():
                with controller.lock:
                    row_index = controller.resume_row
                    if row_index >= len(controller.rows):
                        row_index = None
                    else:
                        controller.resume_row += 1
                    restart = controller.restart_at is not None and row_index == controller.restart_at
                    if restart:
                        controller.restart_at = None
                        controller.clock_base_s = float(controller.rows[row_index][timestamp_column])
                        links = list(controller.links)
                        controller.resume_row = row_index
                    clock_base_s = controller.clock_base_s
                if row_index is None:
                    time.sleep(0.05)
                    continue
                if restart:
                    for link in links:
                        try:
                            link.shutdown(socket.SHUT_RDWR)
                        except OSError:
                            pass
                    return
                row = controller.rows[row_index]
                frame = self.data(row, float(row[timestamp_column]) - clock_base_s)
                self.send(frame)
                sent += 1
                with controller.lock:
                    drop = args.drop_after is not None and sent == args.drop_after and controller.drops_left > 0
                    if drop:
                        controller.drops_left -= 1
                        controller.resume_row += args.skip_on_drop
                    damage = args.damage and sent == args.damage_after and controller.damages_left > 0
                    if damage:
                        controller.damages_left -= 1
                if damage:
                    self.send(self.damaged(args.damage, frame))
                if drop:
                    self.close()
                    return
                if period_s is not None:
                    next_s += period_s
                    delay = next_s - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
        except OSError:
            pass


def dashboard_answer(command: str, args) -> str | None:
    """The dashboard server's answer line to one command line; ``None`` closes the connection."""
    if command == "quit":
        return None
    if command == "get robot model":
        return args.model
    if command == "get serial number":
        return args.serial
    if command == "PolyscopeVersion":
        return "URSoftware {}.{}.{}.{} (Jan 01 2025)".format(*CONTROLLER_VERSION)
    return f"Could not understand: '{command}'"


def serve_dashboard(connection: socket.socket, args) -> None:
    """One dashboard client: the greeting, then a line per command line, until it quits or goes."""
    with connection:
        try:
            connection.sendall(b"Connected: Universal Robots Dashboard Server\n")
            buffer = b""
            while True:
                chunk = connection.recv(4096)
                if not chunk:
                    return
                buffer += chunk
                while b"\n" in buffer:
                    line, buffer = buffer.split(b"\n", 1)
                    answer = dashboard_answer(line.decode(errors="replace").strip(), args)
                    if answer is None:
                        connection.sendall(b"Disconnected\n")
                        return
                    connection.sendall(answer.encode() + b"\n")
        except OSError:
            pass


def dashboard(listener: socket.socket, args) -> None:
    while True:
        try:
            connection, _ = listener.accept()
        except OSError:
            return
        threading.Thread(target=serve_dashboard, args=(connection, args), daemon=True).start()


def listen(port: int) -> socket.socket:
    listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    listener.bind(("127.0.0.1", port))
    listener.listen(16)
    return listener


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--port", type=int, action="append", required=True,
                        help="a controller's port (0: any free one); repeatable")
    parser.add_argument("--recording", required=True, help="ur_rtde CSV: header of RTDE names")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--rate-hz", type=float, default=500.0)
    pace.add_argument("--fast", action="store_true", help="as fast as the client reads")
    parser.add_argument("--protocol", type=int, choices=(1, 2), default=2,
                        help="the newest protocol version accepted (1: an older CB3)")
    parser.add_argument("--drop-after", type=int)
    parser.add_argument("--drop-times", type=int, default=1)
    parser.add_argument("--skip-on-drop", type=int, default=0)
    parser.add_argument("--damage", choices=("size", "recipe", "header", "type", "garbage"))
    parser.add_argument("--damage-after", type=int, default=100)
    parser.add_argument("--damage-times", type=int, default=1)
    parser.add_argument("--restart-after", type=int)
    parser.add_argument("--dashboard-port", type=int, action="append", default=[],
                        help="a controller's dashboard server port (0: any free one), one per --port")
    parser.add_argument("--model", default="UR10", help="the dashboard's answer to 'get robot model'")
    parser.add_argument("--serial", default="20235500001",
                        help="the dashboard's answer to 'get serial number'")
    args = parser.parse_args()
    if args.dashboard_port and len(args.dashboard_port) != len(args.port):
        raise SystemExit("give one --dashboard-port per --port")
    variables, rows = read_recording(args.recording)
    if "timestamp" not in variables:
        raise SystemExit(f"{args.recording}: no timestamp column")
    dashboard_ports = []
    for port in args.dashboard_port:
        listener = listen(port)
        dashboard_ports.append(listener.getsockname()[1])
        threading.Thread(target=dashboard, args=(listener, args), daemon=True).start()
    if dashboard_ports:
        print("dashboard", *dashboard_ports, flush=True)
    ports = []
    for port in args.port:
        listener = listen(port)
        ports.append(listener.getsockname()[1])
        controller = Controller(args, variables, rows)
        threading.Thread(target=controller.serve, args=(listener,), daemon=True).start()
    print("listening", *ports, flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        sys.exit(0)


if __name__ == "__main__":
    main()
