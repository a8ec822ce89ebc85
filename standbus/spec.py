"""Bus specifications as users type them: ``INTERFACE[:CHANNEL][,key=value ...]``.

Examples::

    udp_loopback:stand0          our loopback-pinned multi-process bus (the default)
    socketcan:vcan0              Linux SocketCAN
    pcan:PCAN_USBBUS1,bitrate=500000
    virtual:test                 python-can's in-process bus (unit tests only)

Any interface python-can knows (including plug-ins) is accepted; options are passed to
``can.Bus`` as keyword arguments, with ``true/false`` and numbers converted.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import can


DEFAULT_BUS = "udp_loopback:stand0"


class BusSpecError(ValueError):
    """The bus specification is malformed or names an interface that cannot be opened."""


def _convert(value: str) -> Any:
    lowered = value.lower()
    if lowered in ("true", "yes", "on"):
        return True
    if lowered in ("false", "no", "off"):
        return False
    for kind in (int, float):
        try:
            return kind(value)
        except ValueError:
            pass
    return value


@dataclass(frozen=True)
class BusSpec:
    """A parsed bus specification."""

    interface: str
    channel: str | None = None
    options: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def parse(cls, text: str) -> "BusSpec":
        text = (text or "").strip()
        if not text:
            raise BusSpecError("empty bus specification; use e.g. 'udp_loopback:stand0' or 'socketcan:vcan0'")
        head, *opts = text.split(",")
        interface, sep, channel = head.partition(":")
        interface = interface.strip()
        if not interface:
            raise BusSpecError(f"bus {text!r} has no interface name before ':'")
        options: dict[str, Any] = {}
        for opt in opts:
            key, eq, value = opt.partition("=")
            if not eq or not key.strip():
                raise BusSpecError(
                    f"bus option {opt!r} in {text!r} is not key=value (e.g. bitrate=500000)")
            options[key.strip()] = _convert(value.strip())
        return cls(interface, channel.strip() if sep else None, options)

    def __str__(self) -> str:
        text = self.interface + (f":{self.channel}" if self.channel is not None else "")
        return text + "".join(f",{k}={v}" for k, v in self.options.items())

    def kwargs(self) -> dict[str, Any]:
        kw: dict[str, Any] = {"interface": self.interface, **self.options}
        if self.channel is not None:
            kw["channel"] = self.channel
        return kw


def known_interfaces() -> list[str]:
    from can.interfaces import BACKENDS  # includes entry-point plug-ins
    return sorted(BACKENDS)


def open_bus(spec: "str | BusSpec", **extra: Any) -> "can.BusABC":
    """Open a python-can bus from a spec, turning every failure into a :class:`BusSpecError`
    that says what was wrong and what to try."""
    import can
    if not isinstance(spec, BusSpec):
        spec = BusSpec.parse(spec)
    interfaces = known_interfaces()
    if spec.interface not in interfaces:
        raise BusSpecError(
            f"unknown CAN interface {spec.interface!r}. Known interfaces: {', '.join(interfaces)}. "
            "Write the bus as INTERFACE:CHANNEL, e.g. udp_loopback:stand0 or socketcan:vcan0.")
    try:
        return can.Bus(**spec.kwargs(), **extra)
    except (can.CanError, OSError, ImportError, ValueError, TypeError) as exc:
        hint = ""
        if spec.interface == "socketcan":
            hint = (" (does the interface exist and is it up? e.g. `sudo ip link add dev vcan0 "
                    "type vcan && sudo ip link set up vcan0`; this machine's kernel may lack CAN: "
                    "see scripts/uml-run)")
        raise BusSpecError(f"cannot open CAN bus '{spec}': {exc}{hint}") from exc
