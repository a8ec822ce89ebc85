"""The loopback-pinned multi-process bus (python-can interface ``udp_loopback``)."""
from __future__ import annotations

import os
import select
import shutil
import signal
import socket
import struct
import subprocess
import sys
import threading
import time

import can
import pytest

from tests.support.bus import recv_frames
from standbus import BusSpec, BusSpecError, open_bus
from standbus import wire
from standbus.loopback import LoopbackBus, resolve_channel


def test_wire_format_keeps_every_flag_dlc_and_timestamp():
    msgs = [
        can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False),
        can.Message(arbitration_id=0x1ABCDEF0, data=bytes(8), is_extended_id=True),
        can.Message(arbitration_id=0x7FF, is_remote_frame=True, dlc=5, is_extended_id=False),
        can.Message(arbitration_id=0x20, is_error_frame=True, data=b"\x04", is_extended_id=False),
        can.Message(arbitration_id=0x10, data=bytes(range(64)), is_fd=True, bitrate_switch=True,
                    error_state_indicator=True, is_extended_id=False),
    ]
    for m in msgs:
        back, sender = wire.unpack(wire.pack(m, 42, 1234.5678), "x")
        assert sender == 42 and back.timestamp == 1234.5678
        for attr in ("arbitration_id", "is_extended_id", "is_remote_frame", "is_error_frame",
                     "is_fd", "bitrate_switch", "error_state_indicator", "dlc"):
            assert getattr(back, attr) == getattr(m, attr), attr
        assert bytes(back.data) == bytes(m.data)


@pytest.mark.parametrize("bad", [b"", b"XX" + bytes(30), wire.pack(can.Message(data=b"12"), 1, 0.0)[:-1]])
def test_wire_rejects_malformed_datagrams(bad):
    with pytest.raises(wire.WireFormatError):
        wire.unpack(bad)


def test_frames_go_to_other_instances_not_back_to_the_sender(channel):
    a = LoopbackBus(channel)
    b = LoopbackBus(channel)
    try:
        a.send(can.Message(arbitration_id=0x181, data=b"\x01\x02\x03", is_extended_id=False))
        got = recv_frames(b, 1)
        assert len(got) == 1 and got[0].arbitration_id == 0x181 and bytes(got[0].data) == b"\x01\x02\x03"
        assert abs(got[0].timestamp - time.time()) < 5
        assert a.recv(0.2) is None, "a SocketCAN-like bus does not echo a sender's own frames"
    finally:
        a.shutdown(); b.shutdown()


def test_receive_own_messages_on_request(channel):
    a = LoopbackBus(channel, receive_own_messages=True)
    try:
        a.send(can.Message(arbitration_id=0x55, data=b"\xAA", is_extended_id=False))
        got = recv_frames(a, 1)
        assert got and got[0].arbitration_id == 0x55 and got[0].is_rx is False
    finally:
        a.shutdown()


def test_channels_are_independent_buses(channel):
    a = LoopbackBus(channel)
    other = LoopbackBus(channel + "-other")
    try:
        a.send(can.Message(arbitration_id=0x1, data=b"", is_extended_id=False))
        assert other.recv(0.3) is None
    finally:
        a.shutdown(); other.shutdown()


def test_a_namespace_makes_the_same_channel_name_another_bus(channel, monkeypatch):
    """HYDROSTAND_LOOPBACK_NAMESPACE: one name, a bus per namespace (the documentation tests run
    the docs' default bus so); within a namespace the name is one bus as ever."""
    monkeypatch.setenv("HYDROSTAND_LOOPBACK_NAMESPACE", f"{channel}-ns1")
    a, b = LoopbackBus(channel), LoopbackBus(channel)
    monkeypatch.setenv("HYDROSTAND_LOOPBACK_NAMESPACE", f"{channel}-ns2")
    other = LoopbackBus(channel)
    monkeypatch.delenv("HYDROSTAND_LOOPBACK_NAMESPACE")
    plain = LoopbackBus(channel)
    try:
        assert "namespace" in a.channel_info and a.channel == channel
        a.send(can.Message(arbitration_id=0x181, data=b"\x01", is_extended_id=False))
        assert len(recv_frames(b, 1)) == 1
        assert other.recv(0.3) is None and plain.recv(0.1) is None
    finally:
        for bus in (a, b, other, plain):
            bus.shutdown()


def test_frames_from_one_sender_arrive_in_order(channel):
    a, b = LoopbackBus(channel), LoopbackBus(channel)
    try:
        for i in range(2000):
            a.send(can.Message(arbitration_id=0x200, data=struct.pack("<I", i), is_extended_id=False))
        got = recv_frames(b, 2000, timeout=10)
        assert [struct.unpack("<I", m.data)[0] for m in got] == list(range(2000))
    finally:
        a.shutdown(); b.shutdown()


def test_socket_is_pinned_to_loopback_with_ttl_zero(channel):
    bus = LoopbackBus(channel)
    try:
        sock = bus._socket
        iface = sock.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, 4)
        assert socket.inet_ntoa(iface) == "127.0.0.1"
        assert sock.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL) == 0
        assert sock.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP) == 1
        group, port = resolve_channel(channel)
        assert sock.getsockname()[1] == port and group.startswith("239.255.")
    finally:
        bus.shutdown()


def _non_loopback_interfaces() -> list[str]:
    return [name for _, name in socket.if_nameindex() if name != "lo"]


@pytest.mark.skipif(not hasattr(socket, "AF_PACKET") or os.geteuid() != 0,
                    reason="sniffing interfaces needs Linux AF_PACKET and root")
def test_no_datagram_leaves_loopback(channel):
    """Sniff every non-loopback interface while 1,000 frames cross the bus: none may appear."""
    group, port = resolve_channel(channel)
    sniffers = []
    for name in _non_loopback_interfaces():
        s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(0x0003))
        try:
            s.bind((name, 0))
        except OSError:
            s.close()
            continue
        s.settimeout(0.05)
        sniffers.append((name, s))
    if not sniffers:
        pytest.skip("no non-loopback interface to watch")
    leaked: list[str] = []
    stop = threading.Event()

    def watch(name, s):
        while not stop.is_set():
            try:
                frame = s.recv(65535)
            except (socket.timeout, OSError):
                continue
            # Ethernet + IPv4 + UDP: destination port at 14+20+2
            if len(frame) > 38 and frame[12:14] == b"\x08\x00" and frame[23] == 17:
                ihl = (frame[14] & 0x0F) * 4
                dport = struct.unpack("!H", frame[14 + ihl + 2:14 + ihl + 4])[0]
                if dport == port:
                    leaked.append(name)

    threads = [threading.Thread(target=watch, args=ns, daemon=True) for ns in sniffers]
    for th in threads:
        th.start()
    a, b = LoopbackBus(channel), LoopbackBus(channel)
    try:
        for i in range(1000):
            a.send(can.Message(arbitration_id=0x80, data=bytes([i % 256]), is_extended_id=False))
        assert len(recv_frames(b, 1000, timeout=10)) == 1000, "the bus itself must work meanwhile"
        time.sleep(0.3)
    finally:
        stop.set()
        for th in threads:
            th.join()
        for _, s in sniffers:
            s.close()
        a.shutdown(); b.shutdown()
    assert leaked == [], f"datagrams of the bus seen on {sorted(set(leaked))}"


@pytest.mark.skipif(shutil.which("ip") is None or os.geteuid() != 0, reason="needs iproute2 and root")
def test_bus_works_in_a_namespace_with_only_loopback(tmp_path):
    """In a network namespace whose only interface is lo, two processes still share the bus:
    it needs nothing but loopback."""
    ns = f"standtest{os.getpid()}"
    if subprocess.run(["ip", "netns", "add", ns], capture_output=True).returncode != 0:
        pytest.skip("cannot create a network namespace here")
    try:
        subprocess.run(["ip", "-n", ns, "link", "set", "lo", "up"], check=True)
        links = subprocess.run(["ip", "-n", ns, "-o", "link"], capture_output=True, text=True).stdout
        assert [l.split(":")[1].strip() for l in links.splitlines()] == ["lo"]
        code = (
            "import can, sys, time\n"
            "a = can.Bus(interface='udp_loopback', channel='ns'); b = can.Bus(interface='udp_loopback', channel='ns')\n"
            "a.send(can.Message(arbitration_id=0x701, data=b'\\x05', is_extended_id=False))\n"
            "m = b.recv(2.0); a.shutdown(); b.shutdown()\n"
            "sys.exit(0 if m is not None and m.arbitration_id == 0x701 else 1)\n")
        res = subprocess.run(["ip", "netns", "exec", ns, sys.executable, "-c", code],
                             capture_output=True, text=True, timeout=60)
        assert res.returncode == 0, res.stderr
    finally:
        subprocess.run(["ip", "netns", "del", ns], capture_output=True)


def test_python_can_tools_attach_by_name(channel, tmp_path):
    """``python -m can.logger -i udp_loopback`` joins the emulated bus like any interface."""
    log = tmp_path / "cap.log"
    logger = subprocess.Popen([sys.executable, "-u", "-m", "can.logger", "-i", "udp_loopback", "-c", channel,
                               "-f", str(log)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, bufsize=0,
                              # Ctrl-C stops it, as on a terminal: a job started with `&` by a
                              # non-interactive shell (CI, nohup) hands its children SIGINT ignored
                              preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    said = b""
    try:
        # listening once it says it is connected (its bus is open: frames from then on wait in its
        # socket); a fixed wait was too short on a loaded machine
        deadline = time.monotonic() + 60
        while b"Connected to" not in said:
            assert time.monotonic() < deadline and logger.poll() is None, f"can.logger did not start: {said!r}"
            if select.select([logger.stdout], [], [], 1.0)[0]:
                said += os.read(logger.stdout.fileno(), 4096)
        bus = can.Bus(interface="udp_loopback", channel=channel)
        for i in range(5):
            bus.send(can.Message(arbitration_id=0x182, data=bytes([i, 1, 2]), is_extended_id=False))
            time.sleep(0.01)
        bus.shutdown()
        time.sleep(0.5)
    finally:
        logger.send_signal(signal.SIGINT)
        try:
            rest, _ = logger.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            logger.kill()
            rest, _ = logger.communicate()
            pytest.fail(f"can.logger did not stop on SIGINT within 30 s: {said + rest!r}")
    frames = list(can.LogReader(str(log)))
    assert [bytes(f.data)[0] for f in frames if f.arbitration_id == 0x182] == [0, 1, 2, 3, 4]


def test_bus_spec_parsing_and_clear_errors():
    spec = BusSpec.parse("pcan:PCAN_USBBUS1,bitrate=500000,fd=false")
    assert (spec.interface, spec.channel, spec.options) == ("pcan", "PCAN_USBBUS1", {"bitrate": 500000, "fd": False})
    assert BusSpec.parse("udp_loopback:239.255.0.1:47001").channel == "239.255.0.1:47001"
    with pytest.raises(BusSpecError, match="unknown CAN interface 'nosuch'.*udp_loopback"):
        open_bus("nosuch:x")
    with pytest.raises(BusSpecError, match="key=value"):
        BusSpec.parse("socketcan:vcan0,bitrate")
    with pytest.raises(BusSpecError, match="cannot open CAN bus"):
        open_bus("udp_loopback:300.1.2.3:99")


def test_own_frames_are_dropped_in_the_kernel_and_still_reach_others(channel):
    a, b = LoopbackBus(channel), LoopbackBus(channel)
    own = LoopbackBus(channel, receive_own_messages=True)
    try:
        if sys.platform.startswith("linux"):
            assert a.kernel_self_filter and not own.kernel_self_filter
        for i in range(50):
            a.send(can.Message(arbitration_id=0x300, data=bytes((i,)), is_extended_id=False))
        assert [m.data[0] for m in recv_frames(b, 50)] == list(range(50))
        assert len(recv_frames(own, 50)) == 50
        time.sleep(0.05)
        if a.kernel_self_filter:   # nothing even reached a's socket
            with pytest.raises(BlockingIOError):
                a._socket.recv(100)
        own.send(can.Message(arbitration_id=0x301, data=b"", is_extended_id=False))
        assert [m.arbitration_id for m in recv_frames(own, 1)] == [0x301]
        assert [m.arbitration_id for m in recv_frames(a, 1)] == [0x301]
    finally:
        a.shutdown(); b.shutdown(); own.shutdown()


def test_busy_poll_receives_and_still_times_out(channel):
    from standbus import prefer_busy_poll
    a = LoopbackBus(channel)
    b = LoopbackBus(channel, busy_poll_us=2000)
    off = LoopbackBus(channel, busy_poll_us=0)
    try:
        assert b.busy_poll_s == pytest.approx(0.002) and a.busy_poll_s is None
        assert prefer_busy_poll(a, 0.001) and a.busy_poll_s == 0.001
        assert not prefer_busy_poll(off, 0.001), "an explicit 0 is the user's choice"
        assert prefer_busy_poll(b, 0.001) and b.busy_poll_s == pytest.approx(0.002)
        t0 = time.monotonic()
        assert b.recv(0.05) is None
        assert 0.045 < time.monotonic() - t0 < 1.0
        threading.Timer(0.01, lambda: a.send(can.Message(arbitration_id=0x7, data=b"\x01",
                                                         is_extended_id=False))).start()
        got = b.recv(1.0)     # arrives while polling
        assert got is not None and got.arbitration_id == 0x7
        threading.Timer(0.05, lambda: a.send(can.Message(arbitration_id=0x8, data=b"",
                                                         is_extended_id=False))).start()
        got = b.recv(1.0)     # arrives after the polling window, while sleeping
        assert got is not None and got.arbitration_id == 0x8
    finally:
        a.shutdown(); b.shutdown(); off.shutdown()
    with pytest.raises(can.CanInitializationError, match="busy_poll_us"):
        LoopbackBus(channel, busy_poll_us=-1)
    with pytest.raises(can.CanInitializationError, match="busy_poll_us"):
        LoopbackBus(channel, busy_poll_us="fast")


def test_frames_sent_together_reach_every_bus_stamped_in_order_and_an_unknown_bus_still_gets_its_own(channel):
    """standbus.together: one frame per bus through libc's sendto with the GIL kept; each frame
    is stamped when it was handed over and arrives as if bus.send had sent it; a bus without a
    raw path (python-can's virtual bus) is sent the ordinary way; a bus that fails does not
    keep the frame from the others, and its failure is raised after."""
    from standbus import together
    specs = [f"udp_loopback:{channel}-a", f"udp_loopback:{channel}-b"]
    senders = [open_bus(s) for s in specs]
    listeners = [open_bus(s) for s in specs]
    virtual = can.Bus(interface="virtual", channel=f"{channel}-v")
    virtual_rx = can.Bus(interface="virtual", channel=f"{channel}-v")
    try:
        assert all(together.raw_path(b) is not None for b in senders)
        assert together.raw_path(virtual) is None
        msgs = [can.Message(arbitration_id=0x80, data=b"\x07", is_extended_id=False) for _ in range(3)]
        before = time.time()
        stamps = together.send_together([*senders, virtual], msgs)
        assert before <= stamps[0] <= stamps[1] <= stamps[2] <= time.time()
        assert [m.timestamp for m in msgs] == stamps
        for rx, stamp in zip([*listeners, virtual_rx], stamps):
            got = rx.recv(1.0)
            assert got is not None and got.arbitration_id == 0x80 and bytes(got.data) == b"\x07"
            if rx in listeners:          # the loopback bus carries the sender's stamp
                assert got.timestamp == stamp
        assert all(s.recv(0.05) is None for s in senders), "not back to the sender"

        class Broken(can.BusABC):
            def __init__(self, channel=None, **kwargs):
                super().__init__(channel=channel, **kwargs)

            def send(self, msg, timeout=None):
                raise can.CanOperationError("unplugged")

            def _recv_internal(self, timeout):
                return None, False

        broken = Broken(channel="x")
        msgs = [can.Message(arbitration_id=0x80, data=b"\x08", is_extended_id=False) for _ in range(3)]
        with pytest.raises(can.CanOperationError, match="unplugged"):
            together.send_together([senders[0], broken, senders[1]], msgs)
        assert msgs[1].timestamp == 0.0 and msgs[0].timestamp and msgs[2].timestamp
        assert all(bytes(rx.recv(1.0).data) == b"\x08" for rx in listeners)

        # the same, raw frames (a rig's SYNCs: no Message made): an FD frame on the first bus
        frames = [(wire.FLAG_FD | wire.FLAG_BRS, 0x80, 1, b"\x09"), (0, 0x80, 1, b"\x09"),
                  (0, 0x80, 1, b"\x09")]
        paths = [together.raw_path(b) for b in (*senders, virtual)]
        stamps = [0.0] * 3
        before = time.time()
        assert together.send_frames_together([*senders, virtual], frames, paths, stamps) is stamps
        assert before <= stamps[0] <= stamps[1] <= stamps[2] <= time.time()
        for rx, stamp, fd in zip([*listeners, virtual_rx], stamps, (True, False, False)):
            got = rx.recv(1.0)
            assert got is not None and got.arbitration_id == 0x80 and bytes(got.data) == b"\x09"
            assert got.is_fd == fd and got.bitrate_switch == fd and not got.is_extended_id
            if rx in listeners:
                assert got.timestamp == stamp
        stamps = [0.0] * 3
        with pytest.raises(can.CanOperationError, match="unplugged"):
            together.send_frames_together([senders[0], broken, senders[1]], frames[1:] + frames[1:2],
                                          [paths[0], None, paths[1]], stamps)
        assert stamps[1] == 0.0 and stamps[0] and stamps[2]
        assert all(bytes(rx.recv(1.0).data) == b"\x09" for rx in listeners)
        broken.shutdown()
    finally:
        for b in [*senders, *listeners, virtual, virtual_rx]:
            b.shutdown()
