#!/usr/bin/env python3
"""A Range-capable HTTP server for brickray's remote-store tests (loopback only).

Python's http.server ignores `Range`; this one answers `bytes=a-b`,
`bytes=a-` and `bytes=-N` with 206 and a Content-Range, an unsatisfiable
range with 416, a missing file with 404, and stores PUT bodies (parents
created) so the tests can upload what they read back. Several ranges in one
header are answered with the whole file (200), as RFC 9110 allows.

    python3 range_http.py --root DIR [--port 0] [--port-file FILE]

prints nothing; with --port 0 it picks a free port and writes it to FILE.
"""
import argparse
import email.utils
import hashlib
import os
import re
import sys
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer


class Server(ThreadingHTTPServer):
    # The standard library's listen backlog of 5 drops connections when a
    # client opens dozens at once (they come back after a 1 s SYN retry).
    request_queue_size = 1024

RANGE = re.compile(r"^bytes=(\d*)-(\d*)$")


class Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    root = "."

    def log_message(self, fmt, *args):  # quiet
        pass

    def _path(self):
        rel = self.path.split("?", 1)[0].lstrip("/")
        full = os.path.realpath(os.path.join(self.root, rel))
        root = os.path.realpath(self.root)
        if full != root and not full.startswith(root + os.sep):
            return None
        return full

    def _empty(self, status, headers=()):
        self.send_response(status)
        for k, v in headers:
            self.send_header(k, v)
        self.send_header("Content-Length", "0")
        self.end_headers()

    def _serve(self, head):
        path = self._path()
        if path is None or not os.path.isfile(path):
            self._empty(404)
            return
        st = os.stat(path)
        size = st.st_size
        etag = '"%s"' % hashlib.md5(f"{st.st_mtime_ns}-{size}".encode()).hexdigest()
        common = [
            ("Accept-Ranges", "bytes"),
            ("ETag", etag),
            ("Last-Modified", email.utils.formatdate(st.st_mtime, usegmt=True)),
            ("Content-Type", "application/octet-stream"),
        ]
        start, end, status = 0, size, 200
        header = self.headers.get("Range")
        if header and "," not in header:
            m = RANGE.match(header.strip())
            if not m or (m.group(1) == "" and m.group(2) == ""):
                self._empty(416, [("Content-Range", f"bytes */{size}")])
                return
            a, b = m.group(1), m.group(2)
            if a == "":  # suffix: the last N bytes
                n = int(b)
                if n == 0:
                    self._empty(416, [("Content-Range", f"bytes */{size}")])
                    return
                start = max(0, size - n)
            else:
                start = int(a)
                end = min(size, int(b) + 1) if b != "" else size
                if start >= size or end <= start:
                    self._empty(416, [("Content-Range", f"bytes */{size}")])
                    return
            status = 206
        self.send_response(status)
        for k, v in common:
            self.send_header(k, v)
        if status == 206:
            self.send_header("Content-Range", f"bytes {start}-{end - 1}/{size}")
        self.send_header("Content-Length", str(end - start))
        self.end_headers()
        if head:
            return
        with open(path, "rb") as f:
            f.seek(start)
            left = end - start
            while left > 0:
                chunk = f.read(min(left, 1 << 16))
                if not chunk:
                    break
                self.wfile.write(chunk)
                left -= len(chunk)

    def do_GET(self):
        self._serve(head=False)

    def do_HEAD(self):
        self._serve(head=True)

    def do_PUT(self):
        path = self._path()
        length = self.headers.get("Content-Length")
        if path is None or length is None:
            self._empty(400)
            return
        body = self.rfile.read(int(length))
        os.makedirs(os.path.dirname(path), exist_ok=True)
        tmp = path + ".uploading"
        with open(tmp, "wb") as f:
            f.write(body)
        os.replace(tmp, path)
        self._empty(201)

    def do_DELETE(self):
        path = self._path()
        if path is None or not os.path.isfile(path):
            self._empty(404)
            return
        os.remove(path)
        self._empty(204)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", required=True)
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=0)
    ap.add_argument("--port-file")
    args = ap.parse_args()
    Handler.root = args.root
    server = Server((args.host, args.port), Handler)
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
