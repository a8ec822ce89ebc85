"""Clients that abuse a live page, all at once, for the abuse test (tests/test_live_abuse.py):
run as its own process (``python -m tests.support.abuse PORT ...``, its descriptors its own),
on loopback only. Prints what it saw as one JSON line at the end.

* ``--connections``: that many connections held open from ``--client`` (each opened again a
  second after the server closes it), sending nothing;
* ``--streams``: that many ``GET /live`` from ``--client`` that never read (a 4 kB receive
  buffer, so the server's output waits at once);
* ``--slowloris``: that many connections from ``--client`` sending their headers a byte a
  second (opened again when closed);
* ``--bad``: that many bad requests from ``--bad-client``, 30 at a time (within the server's
  32 connections an address): bad paths, wrong tokens, bodies over the limit, foreign Hosts,
  methods an action does not take, garbage; each answer's status counted (``closed``: none).

All go on for ``--seconds`` and until every bad request is sent (60 s at most).
"""
from __future__ import annotations

import argparse
import asyncio
import collections
import json
import resource
import socket
import time

#: bad requests in flight at once (the server takes 32 connections from an address)
BAD_AT_ONCE = 30
#: how long it goes on at most, s
LONGEST_S = 60.0
BAD = [
    b"GET /static/x%00 HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
    b"GET /static/../../../../etc/passwd HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
    b"GET /static/%ff%fe HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
    b"GET /nothing/here HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
    b"POST /pause HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer not-the-token-0123456789\r\n"
    b"Content-Length: 0\r\n\r\n",
    b"POST /stop HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Basic abc\r\nContent-Length: 0\r\n\r\n",
    b"POST /pause HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 100000000\r\n\r\n" + b"x" * 65536,
    b"GET /status.json HTTP/1.1\r\nHost: evil.example\r\n\r\n",
    b"GET /live HTTP/1.1\r\nHost: evil.example\r\n\r\n",
    b"HEAD /pause HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
    b"OPTIONS /stop HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
    b"TRACE /resume HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
    b"GET /" + b"a" * 9000 + b" HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
    b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03garbage\r\n\r\n",
]


async def _connect(port: int, client: str, rcvbuf: int | None = None) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setblocking(False)
    if rcvbuf:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    sock.bind((client, 0))
    try:
        await asyncio.wait_for(asyncio.get_running_loop().sock_connect(sock, ("127.0.0.1", port)), 5.0)
    except BaseException:
        sock.close()
        raise
    return sock


async def _until_closed(sock: socket.socket, deadline: float) -> None:
    loop = asyncio.get_running_loop()
    while time.monotonic() < deadline:
        try:
            data = await asyncio.wait_for(loop.sock_recv(sock, 65536), deadline - time.monotonic())
        except (asyncio.TimeoutError, OSError):
            return
        if not data:
            return


async def _connected(port: int, client: str, seen: collections.Counter) -> socket.socket | None:
    """A connection, or None a second after it failed (counted)."""
    try:
        return await _connect(port, client)
    except (OSError, asyncio.TimeoutError):
        seen["connect failed"] += 1
        await asyncio.sleep(1.0)
        return None


async def held(port: int, client: str, deadline: float, seen: collections.Counter) -> None:
    while time.monotonic() < deadline:
        sock = await _connected(port, client, seen)
        if sock is None:
            continue
        seen["connected"] += 1
        opened = time.monotonic()
        await _until_closed(sock, deadline)
        sock.close()
        if time.monotonic() < deadline:
            seen["closed by the server at once" if time.monotonic() - opened < 1.0 else "closed by the server"] += 1
            await asyncio.sleep(1.0)


async def stream(port: int, client: str, deadline: float, seen: collections.Counter) -> None:
    try:
        sock = await _connect(port, client, rcvbuf=4096)
        await asyncio.get_running_loop().sock_sendall(sock, b"GET /live HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
    except (OSError, asyncio.TimeoutError):
        seen["failed"] += 1
        return
    seen["sent"] += 1
    await asyncio.sleep(max(deadline - time.monotonic(), 0.0))   # never reads
    sock.close()


async def slowloris(port: int, client: str, deadline: float, seen: collections.Counter) -> None:
    loop = asyncio.get_running_loop()
    while time.monotonic() < deadline:
        sock = await _connected(port, client, seen)
        if sock is None:
            continue
        opened = time.monotonic()
        try:
            await loop.sock_sendall(sock, b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
            while time.monotonic() < deadline:
                await asyncio.sleep(1.0)
                await loop.sock_sendall(sock, b"a")
        except OSError:
            seen["closed by the server"] += 1
            seen["longest held s"] = max(seen["longest held s"], round(time.monotonic() - opened))
        finally:
            sock.close()


async def bad(port: int, client: str, todo: list[int], deadline: float, seen: collections.Counter) -> None:
    loop = asyncio.get_running_loop()
    while todo and time.monotonic() < deadline:
        k = todo.pop()
        try:
            sock = await _connect(port, client)
        except (OSError, asyncio.TimeoutError):
            seen["connect failed"] += 1
            continue
        try:
            await loop.sock_sendall(sock, BAD[k % len(BAD)])
            head = await asyncio.wait_for(loop.sock_recv(sock, 64), 10.0)
            parts = head.split(b" ", 2)
            seen[parts[1].decode() if head.startswith(b"HTTP/1.1 ") else "closed"] += 1
        except (OSError, asyncio.TimeoutError):
            seen["closed"] += 1
        finally:
            sock.close()


async def main(args: argparse.Namespace) -> dict:
    started = time.monotonic()
    hard = started + LONGEST_S
    seen = {k: collections.Counter() for k in ("connections", "streams", "slowloris", "bad")}
    todo = list(range(args.bad))
    workers = [bad(args.port, args.bad_client, todo, hard, seen["bad"]) for _ in range(BAD_AT_ONCE)]
    bad_done = asyncio.ensure_future(asyncio.gather(*workers))
    await asyncio.sleep(0)
    deadline = started + args.seconds
    others = [stream(args.port, args.client, deadline, seen["streams"]) for _ in range(args.streams)]
    others += [held(args.port, args.client, deadline, seen["connections"]) for _ in range(args.connections)]
    others += [slowloris(args.port, args.client, deadline, seen["slowloris"]) for _ in range(args.slowloris)]
    await asyncio.gather(*others)
    while todo and time.monotonic() < hard:              # the rest of the bad ones, and the others with them
        more = min(hard, time.monotonic() + 2.0)
        await asyncio.gather(*[held(args.port, args.client, more, seen["connections"]) for _ in range(100)])
    await bad_done
    return {"seconds": round(time.monotonic() - started, 1), **{k: dict(v) for k, v in seen.items()},
            "bad_not_sent": len(todo)}


if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("port", type=int)
    p.add_argument("--seconds", type=float, default=12.0)
    p.add_argument("--client", default="127.0.0.2")
    p.add_argument("--bad-client", default="127.0.0.3")
    p.add_argument("--connections", type=int, default=1000)
    p.add_argument("--streams", type=int, default=200)
    p.add_argument("--slowloris", type=int, default=8)
    p.add_argument("--bad", type=int, default=5000)
    args = p.parse_args()
    _, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, 8192), hard))
    print(json.dumps(asyncio.run(main(args))), flush=True)
