"""CANopen CiA 402 against independent implementations (python-can, python-canopen) over slcan
on a pseudo-terminal (issue 30.6).

(a) python-canopen's CiA 402 master (`BaseNode402`: SDO, NMT, PDO configuration, the state
    machine) drives exompc's virtual drive served by `exompc cia402 serve` on a pty, through
    python-can's slcan interface.
(b) exompc's CiA 402 master (`exompc cia402 master --port PTY`, its slcan host side as with a
    CANable) drives a python-canopen `LocalNode` whose CiA 402 behaviour is written here, from
    the standard, around the node's SDO callbacks; this file's own slcan adapter puts the
    LocalNode's python-can virtual bus behind the pty.

Both need pseudo-terminals; without them (or without python-can / canopen) the tests report
themselves skipped.
"""

import json
import os
import select
import struct
import subprocess
import threading
import time
import tty

import pytest

can = pytest.importorskip("can", reason="python-can is not installed (pip install python-can)")
canopen = pytest.importorskip("canopen", reason="canopen is not installed (pip install canopen)")
pytest.importorskip("serial", reason="pyserial (python-can's slcan interface) is not installed")
from canopen import objectdictionary as odm  # noqa: E402
from canopen.profiles.p402 import BaseNode402  # noqa: E402

U8, U16, U32 = odm.UNSIGNED8, odm.UNSIGNED16, odm.UNSIGNED32
I8, I16, I32 = odm.INTEGER8, odm.INTEGER16, odm.INTEGER32

# CiA 402 statusword masks (IEC 61800-7-201 Table 30), as the standard writes them.
SW = {
    "NOT READY TO SWITCH ON": (0x4F, 0x00),
    "SWITCH ON DISABLED": (0x4F, 0x40),
    "READY TO SWITCH ON": (0x6F, 0x21),
    "SWITCHED ON": (0x6F, 0x23),
    "OPERATION ENABLED": (0x6F, 0x27),
    "QUICK STOP ACTIVE": (0x6F, 0x07),
    "FAULT REACTION ACTIVE": (0x4F, 0x0F),
    "FAULT": (0x4F, 0x08),
}


def state_of(sw):
    for name, (mask, val) in SW.items():
        if sw & mask == val:
            return name
    return "UNKNOWN"


def need_pty():
    try:
        m, s = os.openpty()
    except OSError as e:
        pytest.skip(f"no pseudo-terminals here ({e})")
    os.close(m)
    os.close(s)


def var(name, index, sub, dtype, access="rw", default=0, pdo=True):
    v = odm.ODVariable(name, index, sub)
    v.data_type = dtype
    v.access_type = access
    v.default = default
    v.pdo_mappable = pdo
    return v


def record(od, name, index, members):
    r = odm.ODRecord(name, index)
    for sub, (mname, dtype, access, default) in enumerate(members):
        r.add_member(var(mname, index, sub, dtype, access, default, pdo=False))
    od.add_object(r)


def cia402_dictionary(node_id, rated_mnm=500):
    """A CiA 402 torque drive's object dictionary (communication and profile objects)."""
    od = odm.ObjectDictionary()
    od.node_id = node_id
    for v in [
        var("Device type", 0x1000, 0, U32, "ro", 0x00020192, False),
        var("Producer heartbeat time", 0x1017, 0, U16, "rw", 0, False),
        var("Error code", 0x603F, 0, U16, "ro", 0),
        var("Controlword", 0x6040, 0, U16, "rw", 0),
        var("Statusword", 0x6041, 0, U16, "ro", 0),
        var("Quick stop option code", 0x605A, 0, I16, "rw", 2, False),
        var("Modes of operation", 0x6060, 0, I8, "rw", 0),
        var("Modes of operation display", 0x6061, 0, I8, "ro", 0),
        var("Position actual value", 0x6064, 0, I32, "ro", 0),
        var("Velocity actual value", 0x606C, 0, I32, "ro", 0),
        var("Target torque", 0x6071, 0, I16, "rw", 0),
        var("Max torque", 0x6072, 0, U16, "rw", 1000),
        var("Motor rated torque", 0x6076, 0, U32, "ro", rated_mnm, False),
        var("Torque actual value", 0x6077, 0, I16, "ro", 0),
        var("Supported drive modes", 0x6502, 0, U32, "ro", (1 << 3) | (1 << 9), False),
    ]:
        od.add_object(v)
    s = odm.VISIBLE_STRING
    od.add_object(var("Manufacturer device name", 0x1008, 0, s, "const", "", False))
    record(od, "Consumer heartbeat time", 0x1016,
           [("Number of entries", U8, "const", 1), ("Consumer 1", U32, "rw", 0)])
    for base, fn in [(0x1400, 0x200), (0x1800, 0x180)]:
        for n in range(4):
            cob = fn + 0x100 * n + node_id
            record(od, f"PDO {base + n:#x} communication", base + n,
                   [("Highest sub-index", U8, "const", 2),
                    ("COB-ID", U32, "rw", cob | 0x80000000),
                    ("Transmission type", U8, "rw", 1)])
            record(od, f"PDO {base + n + 0x200:#x} mapping", base + 0x200 + n,
                   [("Number of entries", U8, "rw", 0)]
                   + [(f"Mapping {i}", U32, "rw", 0) for i in range(1, 9)])
    return od


@pytest.fixture
def served_drive(exompc_bin):
    """`exompc cia402 serve`: a virtual drive (node 5, rated 0.5 N·m, gear 40) on a pty."""
    need_pty()
    p = subprocess.Popen(
        [str(exompc_bin), "cia402", "serve", "--node", "5", "--rated-torque", "0.5",
         "--gear-ratio", "40", "--duration", "60"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = p.stdout.readline()
    if not line.startswith("pty "):
        p.kill()
        err = p.stderr.read()
        if "pseudo-terminal" in err:
            pytest.skip(f"exompc cannot open a pseudo-terminal here: {err.strip()}")
        pytest.fail(f"exompc cia402 serve printed {line!r}, stderr {err!r}")
    yield line.split()[1]
    p.terminate()
    try:
        p.wait(timeout=10)
    except subprocess.TimeoutExpired:
        p.kill()


def test_python_canopen_master_drives_exompcs_virtual_drive(served_drive):
    net = canopen.Network()
    net.connect(interface="slcan", channel=served_drive, bitrate=1_000_000)
    try:
        node = BaseNode402(5, cia402_dictionary(5))
        net.add_node(node)
        node.nmt.state = "PRE-OPERATIONAL"
        # SDO: expedited and segmented uploads, and an abort for a missing object.
        assert node.sdo[0x1000].raw == 0x00020192
        assert node.sdo[0x6076].raw == 500
        assert node.sdo[0x1008].raw == "exompc CiA 402 drive"  # 20 bytes: segmented
        with pytest.raises(canopen.SdoAbortedError) as e:
            node.sdo.upload(0x2345, 0)
        assert e.value.code == 0x06020000
        with pytest.raises(canopen.SdoAbortedError) as e:
            node.sdo[0x6041].raw = 0
        assert e.value.code == 0x06010002
        # Heartbeat, then the PDO mapping written by python-canopen's PdoMap.save().
        node.sdo[0x1017].raw = 50
        assert node.nmt.wait_for_heartbeat(1.0) == "PRE-OPERATIONAL"
        node.tpdo.read()
        node.rpdo.read()
        assert not node.tpdo[1].enabled, "the drive starts with its PDOs disabled"
        for n, objs in [(1, [0x6041, 0x6064]), (2, [0x606C, 0x6077, 0x6061])]:
            node.tpdo[n].clear()
            for o in objs:
                node.tpdo[n].add_variable(o)
            node.tpdo[n].trans_type = 1
            node.tpdo[n].enabled = True
            node.tpdo[n].save()
        node.rpdo[1].clear()
        node.rpdo[1].add_variable(0x6040)
        node.rpdo[1].add_variable(0x6071)
        node.rpdo[1].trans_type = 255
        node.rpdo[1].enabled = True
        node.rpdo[1].save()
        # A mapping of a read-only object into an RPDO is refused (CiA 301: 0x06040041).
        node.rpdo[2].clear()
        node.rpdo[2].add_variable(0x6041)
        node.rpdo[2].enabled = True
        with pytest.raises(canopen.SdoAbortedError) as e:
            node.rpdo[2].save()
        assert e.value.code == 0x06040041
        node.setup_402_state_machine(read_pdos=False)
        node.sdo[0x605A].raw = 6  # quick stop: stay in QUICK STOP ACTIVE
        net.sync.start(0.01)
        node.nmt.state = "OPERATIONAL"
        assert node.nmt.wait_for_heartbeat(1.0) == "OPERATIONAL"
        node.op_mode = "CYCLIC SYNCHRONOUS TORQUE"
        assert node.op_mode == "CYCLIC SYNCHRONOUS TORQUE"
        # The state machine, step by step through python-canopen's transition table.
        node.tpdo[1].wait_for_reception(1.0)
        assert node.state == "SWITCH ON DISABLED"
        for target in ["READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED"]:
            node.state = target
            assert node.state == target
        # 3 N·m at the joint = 150 per mille of 0.5 N·m × 40.
        node.rpdo[1][0x6071].raw = 150
        node.rpdo[1].transmit()
        time.sleep(0.3)
        node.tpdo[2].wait_for_reception(1.0)
        pos0 = node.tpdo_values[0x6064]
        assert node.tpdo_values[0x6077] == 150
        assert node.tpdo_values[0x6061] == 10
        time.sleep(0.2)
        node.tpdo[1].wait_for_reception(1.0)
        node.tpdo[2].wait_for_reception(1.0)
        assert node.tpdo_values[0x6064] > pos0 > 0, "the joint turns under positive torque"
        assert node.tpdo_values[0x606C] > 0
        # The drive's own limit: 0x6072 = 100 per mille cuts a 300 per mille target, and the
        # statusword shows "internal limit active" (bit 11).
        node.sdo[0x6072].raw = 100
        node.rpdo[1][0x6071].raw = 300
        node.rpdo[1].transmit()
        time.sleep(0.05)
        node.tpdo[2].wait_for_reception(1.0)
        node.tpdo[1].wait_for_reception(1.0)
        assert node.tpdo_values[0x6077] == 100
        assert node.statusword & 0x0800
        # Quick stop: torque off at once.
        node.state = "QUICK STOP ACTIVE"
        time.sleep(0.05)
        node.tpdo[2].wait_for_reception(1.0)
        assert node.tpdo_values[0x6077] == 0
        node.state = "SWITCH ON DISABLED"
        # A heartbeat consumer on the drive for a master node 0x7E: one heartbeat, then
        # silence → fault with EMCY 0x8130; python-canopen resets it through the table.
        node.sdo[0x1016][1].raw = (0x7E << 16) | 100
        node.state = "OPERATION ENABLED"
        net.send_message(0x77E, [0x05])
        emcy = node.emcy.wait(0x8130, timeout=2.0)
        assert emcy is not None and emcy.code == 0x8130
        node.tpdo[1].wait_for_reception(1.0)
        assert node.state == "FAULT"
        node.sdo[0x1016][1].raw = 0
        node.state = "OPERATION ENABLED"
        assert node.state == "OPERATION ENABLED"
        assert node.sdo[0x603F].raw == 0x8130, "the last error code stays readable"
        node.state = "SWITCH ON DISABLED"
    finally:
        net.sync.stop()
        net.disconnect()


class SlcanAdapter(threading.Thread):
    """The adapter side of slcan (Lawicel) on a pty, written here from the protocol: puts a
    python-can bus behind the pty as a CANable puts a CAN bus behind its USB port."""

    def __init__(self, bus):
        super().__init__(daemon=True)
        self.bus = bus
        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        self.slave = slave
        self.open = False
        self.stop = False
        self.errors = []

    def write(self, b):
        os.write(self.master, b)

    def line(self, ln):
        c = ln[:1]
        if c in (b"t", b"T") and self.open:
            n = 3 if c == b"t" else 8
            can_id = int(ln[1:1 + n], 16)
            dlc = int(ln[1 + n:2 + n], 16)
            data = bytes.fromhex(ln[2 + n:2 + n + 2 * dlc].decode())
            self.bus.send(can.Message(arbitration_id=can_id, data=data,
                                      is_extended_id=c == b"T"))
            self.write(b"z\r" if c == b"t" else b"Z\r")
        elif c == b"O":
            self.open = True
            self.write(b"\r")
        elif c == b"C":
            self.open = False
            self.write(b"\r")
        elif c in (b"S", b"V", b"N"):
            self.write(b"\r" if c == b"S" else c + b"0101\r")
        elif c == b"F":
            self.write(b"F00\r")
        else:
            self.errors.append(ln)
            self.write(b"\x07")

    def run(self):
        buf = b""
        while not self.stop:
            r, _, _ = select.select([self.master], [], [], 0.001)
            if r:
                try:
                    buf += os.read(self.master, 4096)
                except OSError:
                    return
                while b"\r" in buf:
                    ln, buf = buf.split(b"\r", 1)
                    if ln:
                        self.line(ln)
            while True:
                m = self.bus.recv(0)
                if m is None:
                    break
                if self.open and not m.is_error_frame:
                    idf = f"T{m.arbitration_id:08X}" if m.is_extended_id else f"t{m.arbitration_id:03X}"
                    self.write(f"{idf}{m.dlc}{bytes(m.data).hex().upper()}\r".encode())


class Cia402Node:
    """A CiA 402 drive on python-canopen's LocalNode: the state machine, PDOs by the mapping
    the master wrote, a simple inertia load, all written here from the standard."""

    def __init__(self, net, node_id):
        self.node = canopen.LocalNode(node_id, cia402_dictionary(node_id))
        net.add_node(self.node)
        self.net = net
        self.id = node_id
        self.state = "SWITCH ON DISABLED"
        self.last_cw = 0
        self.controlwords = []
        self.torques = []
        self.q = 0.0
        self.qd = 0.0
        self.lock = threading.Lock()
        self.node.add_write_callback(self.on_write)
        net.subscribe(0x80, self.on_sync)
        net.subscribe(0x200 + node_id, self.on_rpdo)
        self.publish()

    def get(self, index, sub=0):
        if isinstance(self.node.object_dictionary[index], odm.ODVariable):
            return self.node.sdo[index].raw
        return self.node.sdo[index][sub].raw

    def put(self, index, value, fmt):
        self.node.set_data(index, 0, struct.pack(fmt, value))

    def publish(self):
        sw = {"NOT READY TO SWITCH ON": 0x00, "SWITCH ON DISABLED": 0x40,
              "READY TO SWITCH ON": 0x31, "SWITCHED ON": 0x33, "OPERATION ENABLED": 0x37,
              "QUICK STOP ACTIVE": 0x17, "FAULT": 0x08}[self.state]
        self.put(0x6041, sw | 0x0200, "<H")

    def on_controlword(self, cw):
        self.controlwords.append(cw)
        s = self.state
        reset_edge = cw & 0x80 and not self.last_cw & 0x80
        self.last_cw = cw
        if s == "FAULT":
            s = "SWITCH ON DISABLED" if reset_edge else s
        elif not cw & 0x02:
            s = "SWITCH ON DISABLED"
        elif not cw & 0x04:
            s = "QUICK STOP ACTIVE" if s == "OPERATION ENABLED" else "SWITCH ON DISABLED"
        elif cw & 0x0F == 0x06:
            s = "READY TO SWITCH ON"
        elif cw & 0x0F == 0x07 and s in ("READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED"):
            s = "SWITCHED ON"
        elif cw & 0x0F == 0x0F and s in ("READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED",
                                          "QUICK STOP ACTIVE"):
            s = "OPERATION ENABLED"
        self.state = s
        self.publish()

    def on_write(self, index, subindex, od, data):
        if index == 0x6040:
            with self.lock:
                self.on_controlword(struct.unpack("<H", data)[0])
        elif index == 0x6060:
            self.node.data_store.setdefault(0x6061, {})[0] = bytes(data)

    def mapping(self, comm, mapping):
        cob = self.get(comm, 1)
        if cob & 0x80000000:
            return None, []
        n = self.get(mapping, 0)
        return cob & 0x7FF, [self.get(mapping, i) for i in range(1, n + 1)]

    def on_rpdo(self, can_id, data, timestamp):
        _, entries = self.mapping(0x1400, 0x1600)
        off = 0
        for e in entries:
            index, sub, size = e >> 16, (e >> 8) & 0xFF, (e & 0xFF) // 8
            self.node.set_data(index, sub, bytes(data[off:off + size]))
            off += size

    def on_sync(self, can_id, data, timestamp):
        if self.node.nmt.state != "OPERATIONAL":
            return
        with self.lock:
            target = self.get(0x6071)
            limit = self.get(0x6072)
            pm = max(-limit, min(limit, target)) if self.state == "OPERATION ENABLED" else 0
            self.torques.append(pm)
            tau = pm / 1000 * 0.5 * 40  # joint N·m
            self.qd += 0.01 * (tau - 2.0 * self.qd) / 0.5
            self.q += 0.01 * self.qd
            self.put(0x6077, pm, "<h")
            self.put(0x6064, round(self.q / (2 * 3.141592653589793) * 4096 * 40), "<i")
            self.put(0x606C, round(self.qd * 40 * 60 / (2 * 3.141592653589793)), "<i")
        for comm, mp in [(0x1800 + n, 0x1A00 + n) for n in range(4)]:
            cob, entries = self.mapping(comm, mp)
            if cob is None or not entries:
                continue
            payload = b""
            for e in entries:
                index, sub = e >> 16, (e >> 8) & 0xFF
                payload += self.node.get_data(index, sub)
            self.net.send_message(cob, payload)


def test_exompcs_master_drives_a_python_canopen_local_node(exompc_bin):
    need_pty()
    vbus = can.Bus(interface="virtual", channel="exompc-peer-b", receive_own_messages=False)
    net = canopen.Network()
    net.connect(interface="virtual", channel="exompc-peer-b")
    adapter = SlcanAdapter(vbus)
    adapter.start()
    try:
        drive = Cia402Node(net, 6)
        drive.node.nmt.state = "PRE-OPERATIONAL"
        r = subprocess.run(
            [str(exompc_bin), "cia402", "master", "--port", adapter.path, "--node", "6",
             "--rated-torque", "0.5", "--gear-ratio", "40", "--torque", "3", "--max-torque", "8",
             "--cycles", "40", "--rate", "100"],
            capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, r.stderr
        lines = [json.loads(x) for x in r.stdout.splitlines()]
        assert lines[0] == {"event": "enabled", "node": 6}
        samples = [x for x in lines if "cycle" in x]
        assert lines[-1] == {"event": "stopped", "samples": len(samples)}
        assert len(samples) >= 35, f"{len(samples)} of 40 periods had both TPDOs"
        # What exompc configured, read back from the LocalNode's dictionary.
        assert drive.get(0x6060) == 10
        assert drive.get(0x6072) == 400, "8 N·m = 400 per mille of 0.5 N·m × 40"
        assert drive.get(0x1017) == 50
        assert drive.get(0x1016, 1) == (127 << 16) | 150
        assert drive.mapping(0x1400, 0x1600) == (0x206, [0x60400010, 0x60710010])
        assert drive.mapping(0x1800, 0x1A00) == (0x186, [0x60410010, 0x60640020])
        assert drive.mapping(0x1801, 0x1A01) == (0x286, [0x606C0020, 0x60770010])
        assert drive.get(0x1802, 1) & 0x80000000, "unused TPDOs disabled"
        # The walk: disable voltage, shutdown, switch on, enable operation; the RPDOs keep
        # 0x0F; the last controlword is the quick stop.
        cws = drive.controlwords
        assert cws[:4] == [0x00, 0x06, 0x07, 0x0F], cws[:8]
        assert cws[-1] == 0x02
        assert drive.state == "QUICK STOP ACTIVE"
        # 3 N·m = 150 per mille, applied from the first SYNC after enabling on.
        assert 150 in drive.torques and max(drive.torques) == 150
        last = samples[-1]
        assert abs(last["torque"] - 3.0) < 1e-9
        assert state_of(last["statusword"]) == "OPERATION ENABLED"
        assert last["position"] > 0 and last["velocity"] > 0
        assert not adapter.errors, adapter.errors
    finally:
        adapter.stop = True
        adapter.join(timeout=2)
        net.disconnect()
        vbus.shutdown()
