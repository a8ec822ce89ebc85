"""Where the live page listens and who may address it: ``--serve``, ``--allow-host``, ``--tls-cert``
and ``--tls-key`` checked together before anything starts (docs/endurance.md, the live page).

* **Loopback** (``127.0.0.1``, ``::1``, ``localhost``; the default): plain HTTP or HTTPS.
* **Any other address** (``0.0.0.0``, a control room's interface) listens beyond this computer:
  it needs the names the control room uses for it (``--allow-host``, repeatable); and with the
  operator's token, HTTPS (``--tls-cert``, ``--tls-key``): a token must not cross a network in
  clear. Without the token such a page is read-only, and if served on plain HTTP says so.
* **The Host check is never off**: a request is answered only if its ``Host`` is a loopback
  name or address, an allowed name, or the address the server is bound to. A web page elsewhere
  cannot then read the test through a DNS name it points at this computer (DNS rebinding): the
  browser sends that name.
"""
from __future__ import annotations

import ipaddress
import os
import socket
import ssl
import stat
from dataclasses import dataclass, field
from pathlib import Path

from core.errors import ParameterError

LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})
#: connections the kernel keeps waiting for the server (while it starts again, say)
BACKLOG = 128
#: the kernel's send buffer of each connection (inherited from the listening socket), bytes: a
#: client that stops reading holds at most this of the host's memory (Linux doubles it) until
#: the write timeout closes it, not the megabytes autotuning would grow to
SEND_BUFFER_BYTES = 256 * 1024
#: what a certificate is made with, for the messages
CERT_HINT = ("openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -days 825 "
             "-subj /CN=HOST -addext subjectAltName=DNS:HOST -keyout key.pem -out cert.pem; chmod 600 key.pem")


def is_loopback_host(host: str) -> bool:
    host = host.strip("[]").lower()
    if host in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@dataclass(frozen=True)
class Address:
    host: str
    port: int

    @property
    def loopback(self) -> bool:
        return is_loopback_host(self.host)

    @property
    def everywhere(self) -> bool:
        """Bound to every interface (``0.0.0.0``, ``::``)."""
        try:
            return ipaddress.ip_address(self.host).is_unspecified
        except ValueError:
            return False

    def url(self, port: int | None = None, tls: bool = False, host: str | None = None) -> str:
        host = host or self.host
        host = f"[{host}]" if ":" in host else host
        return f"{'https' if tls else 'http'}://{host}:{self.port if port is None else port}/"


def serve_address(text: str) -> Address:
    """``--serve``'s value: ``HOST:PORT``, ``[IPV6]:PORT``, ``:PORT`` or ``PORT`` (then
    127.0.0.1); port 0: any free one."""
    value = text.strip()
    host, port = "127.0.0.1", value
    if value.startswith("["):
        inside, _, rest = value[1:].partition("]")
        if not rest.startswith(":"):
            raise ParameterError(f"--serve {text}: give [IPV6]:PORT, e.g. [::1]:8080")
        host, port = inside, rest[1:]
    elif ":" in value:
        host, _, port = value.rpartition(":")
        host = host or "127.0.0.1"
        if ":" in host:
            raise ParameterError(f"--serve {text}: an IPv6 address goes in brackets, e.g. [::1]:8080")
    if not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ParameterError(f"--serve {text}: give HOST:PORT with a port 0-65535, e.g. 127.0.0.1:8080 "
                             "(a port alone serves on 127.0.0.1)")
    return Address(host, int(port))


def _allowed_name(name: str) -> str:
    value = name.strip().lower().rstrip(".")
    if value.startswith("[") and value.endswith("]"):
        value = value[1:-1]
    ok = bool(value) and len(value) <= 253 and all(c.isalnum() or c in "-.:" for c in value)
    if not ok:
        raise ParameterError(f"--allow-host {name!r}: give a host name or address the control room uses "
                             "for this computer, e.g. --allow-host rig-pc.lab.example")
    return value


def _private_file(path: str, option: str) -> Path:
    """A file the server will read: there, a plain file (checked before it is opened)."""
    p = Path(path)
    try:
        info = os.stat(p)
    except OSError as exc:
        raise ParameterError(f"{option} {path}: {exc.strerror or exc}") from None
    if not stat.S_ISREG(info.st_mode):
        raise ParameterError(f"{option} {path}: not a plain file")
    return p


@dataclass(frozen=True)
class Binding:
    """The page's address, the names it answers to and its certificate (module docstring)."""

    address: Address
    allow_hosts: tuple[str, ...] = ()
    tls_cert: str | None = None
    tls_key: str | None = None
    token: bool = False
    #: set by :meth:`check`: the names a request's Host may carry besides loopback's
    hosts: frozenset[str] = field(default=frozenset())

    @property
    def tls(self) -> bool:
        return self.tls_cert is not None

    @classmethod
    def check(cls, serve: str, allow_hosts: list[str] | None = None, tls_cert: str | None = None,
              tls_key: str | None = None, token: bool = False) -> "Binding":
        """The options checked together (module docstring); a :class:`ParameterError` that says
        what to give for a combination that would expose the test."""
        address = serve_address(serve)
        names = tuple(dict.fromkeys(_allowed_name(n) for n in allow_hosts or ()))
        if (tls_cert is None) != (tls_key is None):
            raise ParameterError("--tls-cert and --tls-key go together: the certificate (PEM) and its private key")
        where = f"--serve {serve}"
        if not address.loopback:
            if not names:
                raise ParameterError(
                    f"{where} listens beyond this computer: name the host names the control room uses for it "
                    "with --allow-host NAME (repeatable, e.g. --allow-host rig-pc.lab.example); a request for "
                    "any other name is refused, so a web page elsewhere cannot read the test")
            if token and tls_cert is None:
                raise ParameterError(
                    f"{where} with --operator-token-file on plain HTTP: the token would cross the network in "
                    "clear. Give the page a certificate with --tls-cert CERT.pem --tls-key KEY.pem (the control "
                    f"room's, or a self-signed one: {CERT_HINT}), or serve on 127.0.0.1 and reach it through "
                    "an SSH tunnel (ssh -L 8080:127.0.0.1:8080 HOST)")
        binding = cls(address, names, tls_cert, tls_key, token, frozenset(names) | _own_names(address))
        if binding.tls:
            binding.tls_context()                   # a clear error now, not in the server
        return binding

    def host_allowed(self, host: str) -> bool:
        """Whether a request whose ``Host`` names ``host`` (without the port) is answered."""
        name = host.strip().lower().rstrip(".")
        if name.startswith("[") and name.endswith("]"):
            name = name[1:-1]
        return is_loopback_host(name) or name in self.hosts

    def tls_context(self) -> ssl.SSLContext | None:
        """The server's TLS context (None: plain HTTP); a clear error for files that are not
        there, a key others may read, or a certificate and key that do not belong together."""
        if not self.tls:
            return None
        cert = _private_file(self.tls_cert, "--tls-cert")
        key = _private_file(self.tls_key, "--tls-key")
        mode = stat.S_IMODE(os.stat(key).st_mode)
        if mode & 0o077:
            raise ParameterError(f"--tls-key {key}: others may read it (mode {mode:04o}); chmod 600 {key}")
        context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        context.minimum_version = ssl.TLSVersion.TLSv1_2
        try:
            context.load_cert_chain(cert, key)
        except (ssl.SSLError, OSError, ValueError) as exc:
            raise ParameterError(f"--tls-cert {cert} --tls-key {key}: cannot use them ({exc}); give a PEM "
                                 f"certificate and its private key ({CERT_HINT})") from None
        return context

    def url(self, port: int) -> str:
        """The page's URL: on loopback or a named address as bound, else at the first allowed
        name (what the control room types)."""
        host = self.allow_hosts[0] if self.address.everywhere and self.allow_hosts else None
        return self.address.url(port, self.tls, host)

    def exposure(self, port: int) -> str:
        """What the page exposes, for the line the command prints."""
        if self.address.loopback:
            return ""
        where = "every interface" if self.address.everywhere else self.address.host
        how = "HTTPS" if self.tls else "plain HTTP: what it shows crosses the network in clear"
        return (f"listening on {where} port {port} for {', '.join(self.allow_hosts)} ({how}): anyone who can "
                "reach this computer sees the test's signals, status and events")


def _own_names(address: Address) -> frozenset[str]:
    """A specific address the server is bound to is a name a request may carry."""
    if address.everywhere:
        return frozenset()
    return frozenset({address.host.lower()})


def bind_listeners(address: Address) -> list[socket.socket]:
    """Listening sockets for ``address`` (both families for ``localhost``); a clear error when
    nothing can listen there. The session holds them and hands them to each server process it
    starts: the port stays while a server is started again."""
    import tornado.netutil
    try:
        sockets = tornado.netutil.bind_sockets(address.port, address.host, family=socket.AF_UNSPEC,
                                               backlog=BACKLOG)
    except (OSError, socket.gaierror) as exc:
        raise ParameterError(f"--serve {address.host}:{address.port}: cannot listen there "
                             f"({exc.strerror or exc})") from None
    for sock in sockets:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER_BYTES)
    return sockets
