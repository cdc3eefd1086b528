#!/usr/bin/env python3
"""A fault-injecting HTTP proxy for brickray's remote-store tests (loopback only).

Forwards each request to --upstream (the S3 or Range HTTP test server) and,
by a fixed cycle over the requests it sees, injects a fault instead of (or
into) the answer:

    latency   the answer after 5 to 60 ms (jitter)
    503, 429  an error status with no body (Retry-After: 0)
    reset     the connection closed without an answer
    truncate  the headers, then half the body, then the connection closed
    stall     the headers, then a third of the body, then nothing for --stall s

    python3 fault_proxy.py --upstream http://127.0.0.1:PORT
        [--cycle ok,503,latency,reset,ok,429,truncate,stall] [--port 0]
        [--port-file FILE] [--stall 30] [--delay MS]

--delay holds every request MS milliseconds before it is forwarded: an
added round-trip time (the `remote` benchmark runs `--cycle ok --delay 80`).

Every connection carries one request (Connection: close), so a fault never
leaks into the next request. Standard library only.
"""
import argparse
import http.client
import os
import random
import socket
import sys
import threading
import time
import urllib.parse
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer


class Server(ThreadingHTTPServer):
    # The standard library's listen backlog of 5 drops connections when a
    # client opens dozens at once (they come back after a 1 s SYN retry).
    request_queue_size = 1024

HOP = {"connection", "keep-alive", "proxy-connection", "transfer-encoding", "upgrade", "te", "trailer"}


class Proxy(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    upstream = None
    cycle = ["ok"]
    stall = 30.0
    delay = 0.0
    counter = 0
    lock = threading.Lock()

    def log_message(self, fmt, *args):
        pass

    def _fault(self):
        with Proxy.lock:
            n = Proxy.counter
            Proxy.counter += 1
        return Proxy.cycle[n % len(Proxy.cycle)]

    def _forward(self):
        length = int(self.headers.get("Content-Length") or 0)
        body = self.rfile.read(length) if length else None
        fault = self._fault()
        if Proxy.delay > 0:
            time.sleep(Proxy.delay)
        if fault == "reset":
            # RST rather than FIN: SO_LINGER with a zero timeout.
            self.connection.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")
            self.connection.close()
            self.close_connection = True
            return
        if fault in ("503", "429"):
            self.send_response(int(fault))
            self.send_header("Retry-After", "0")
            self.send_header("Content-Length", "0")
            self.send_header("Connection", "close")
            self.end_headers()
            self.close_connection = True
            return
        if fault == "latency":
            time.sleep(random.uniform(0.005, 0.06))
        up = urllib.parse.urlsplit(Proxy.upstream)
        conn = http.client.HTTPConnection(up.hostname, up.port, timeout=30)
        headers = {k: v for k, v in self.headers.items() if k.lower() not in HOP}
        conn.request(self.command, self.path, body=body, headers=headers)
        resp = conn.getresponse()
        data = resp.read()
        conn.close()
        self.send_response(resp.status, resp.reason)
        for k, v in resp.getheaders():
            if k.lower() not in HOP and k.lower() != "content-length":
                self.send_header(k, v)
        # A HEAD's length is the object's (its answer has no body).
        length = resp.getheader("Content-Length") if self.command == "HEAD" else None
        self.send_header("Content-Length", length or str(len(data)))
        self.send_header("Connection", "close")
        self.end_headers()
        self.close_connection = True
        if self.command == "HEAD":
            return
        if fault == "truncate" and len(data) > 1:
            self.wfile.write(data[: len(data) // 2])
            self.wfile.flush()
            self.connection.shutdown(socket.SHUT_RDWR)
            return
        if fault == "stall" and len(data) > 2:
            self.wfile.write(data[: len(data) // 3])
            self.wfile.flush()
            time.sleep(Proxy.stall)
            return
        self.wfile.write(data)

    do_GET = do_HEAD = do_PUT = do_POST = do_DELETE = _forward


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--upstream", required=True)
    ap.add_argument("--cycle", default="ok,503,latency,reset,ok,429,truncate,ok,stall")
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=0)
    ap.add_argument("--port-file")
    ap.add_argument("--stall", type=float, default=30.0)
    ap.add_argument("--delay", type=float, default=0.0, help="ms added to every request")
    args = ap.parse_args()
    Proxy.upstream = args.upstream
    Proxy.cycle = [c.strip() for c in args.cycle.split(",") if c.strip()]
    Proxy.stall = args.stall
    Proxy.delay = args.delay / 1000.0
    server = Server((args.host, args.port), Proxy)
    server.daemon_threads = True
    if args.port_file:
        with open(args.port_file + ".tmp", "w") as f:
            f.write(str(server.server_address[1]))
        os.replace(args.port_file + ".tmp", args.port_file)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
