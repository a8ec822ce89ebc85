"""Layer setting services, the device's side (CiA 305): how a fresh device without a node id is
found and given one.

An emulated node can start *unconfigured* (``stand emulate --unconfigured CHANNEL``): it has no
node id, sends no boot-up and answers nothing but LSS (master → device on 0x7E5, device →
master on 0x7E4). Its LSS address is its identity (0x1018: vendor, product, revision, serial).

* **switch state global** (0x04): all devices to waiting (0) or configuration (1);
* **switch state selective** (0x40-0x43): the device whose four identity values match goes
  to configuration and answers 0x44;
* **fastscan** (0x51): a device without a node id answers 0x4F while the bits of its address from
  the checked bit up match the master's; the master finds its address bit by bit, the last
  message moves it to configuration;
* **identify non-configured remote slave** (0x4C): a device without a node id answers 0x50;
* in configuration: **configure node id** (0x11), **configure bit timing** (0x13, 0x15: taken,
  the emulated bus has no bit rate), **store configuration** (0x17), **inquire** the identity
  (0x5A-0x5D) and the node id (0x5E);
* back to waiting with a new node id, the device takes it and boots (its boot-up on 0x700 + id):
  :meth:`plant_emulator.node.EmulatedNode.take_node_id`.
"""
from __future__ import annotations

import logging
import struct

log = logging.getLogger(__name__)

LSS_MASTER, LSS_DEVICE = 0x7E5, 0x7E4
UNCONFIGURED = 0xFF
WAITING, CONFIGURATION = 0, 1


class LssDevice:
    """The LSS side of one emulated node (``node``: :class:`~plant_emulator.node.EmulatedNode`).
    ``identity``: vendor, product, revision, serial (its LSS address)."""

    def __init__(self, node, identity: tuple[int, int, int, int], node_id: int = UNCONFIGURED) -> None:
        self.node = node
        self.identity = tuple(int(v) & 0xFFFFFFFF for v in identity)
        self.state = WAITING
        #: the node id in use (0xFF: none), and the one configured to take at the next waiting
        self.active_id = node_id
        self.pending_id = node_id
        self._selective: list[int] = []
        self._fastscan_sub = 0
        self.stored = False

    @property
    def configured(self) -> bool:
        return 1 <= self.active_id <= 127

    def _send(self, *payload: int) -> None:
        data = bytes(payload) + bytes(8 - len(payload))
        self.node.network.send_message(LSS_DEVICE, data)

    def on_request(self, can_id: int, data: bytes, timestamp: float) -> None:
        if len(data) != 8:
            return
        with self.node.lock:
            self._handle(data)

    def _handle(self, data: bytes) -> None:
        cs = data[0]
        if cs == 0x04:                                       # switch state global
            self._switch(data[1])
        elif 0x40 <= cs <= 0x43:                             # switch state selective
            value = struct.unpack_from("<I", data, 1)[0]
            if cs == 0x40:
                self._selective = []
            if len(self._selective) == cs - 0x40:
                self._selective.append(value)
            if len(self._selective) == 4:
                if tuple(self._selective) == self.identity:
                    self.state = CONFIGURATION
                    self._send(0x44)
                self._selective = []
        elif cs == 0x4C:                                     # identify non-configured slave
            if not 1 <= self.pending_id <= 127:
                self._send(0x50)
        elif cs == 0x51:                                     # fastscan
            self._fastscan(data)
        elif self.state == CONFIGURATION:
            self._configure(cs, data)

    def _switch(self, mode: int) -> None:
        if mode == CONFIGURATION:
            self.state = CONFIGURATION
            return
        self.state = WAITING
        if self.pending_id != self.active_id and 1 <= self.pending_id <= 127:
            self.active_id = self.pending_id
            log.info("LSS: %08X:%08X serial %08X takes node id %d", self.identity[0],
                     self.identity[1], self.identity[3], self.active_id)
            self.node.take_node_id(self.active_id)

    def _fastscan(self, data: bytes) -> None:
        if 1 <= self.pending_id <= 127:                     # only devices without a node id
            return
        id_number, bit, sub, nxt = struct.unpack_from("<IBBB", data, 1)
        if bit == 0x80:                                      # the scan begins: all answer
            self._fastscan_sub = 0
            self._send(0x4F)
            return
        if bit > 31 or sub != self._fastscan_sub or sub > 3:
            return
        mask = (0xFFFFFFFF << bit) & 0xFFFFFFFF
        if (id_number & mask) != (self.identity[sub] & mask):
            return
        self._send(0x4F)
        if bit == 0:                                         # this part of the address is known
            self._fastscan_sub = nxt
            if nxt <= sub:                                   # the whole address: found
                self.state = CONFIGURATION

    def _configure(self, cs: int, data: bytes) -> None:
        if cs == 0x11:                                       # configure node id
            nid = data[1]
            ok = 1 <= nid <= 127 or nid == UNCONFIGURED
            if ok:
                self.pending_id = nid
            self._send(0x11, 0 if ok else 1)
        elif cs == 0x13:                                     # configure bit timing
            ok = data[1] == 0 and data[2] <= 8               # the CiA bit timing table
            self._send(0x13, 0 if ok else 1)
        elif cs == 0x15:                                     # activate bit timing: no answer
            pass
        elif cs == 0x17:                                     # store configuration
            self.stored = True
            self._send(0x17, 0)
        elif 0x5A <= cs <= 0x5D:                             # inquire identity
            self._send(cs, *struct.pack("<I", self.identity[cs - 0x5A]))
        elif cs == 0x5E:                                     # inquire node id
            self._send(0x5E, self.active_id)
