#!/usr/bin/env python3
"""The S3 server the bucket tests run against (`.ci/run`): moto's S3 backend and Flask app, served
on loopback, with every request handled one at a time.

Why one at a time: S3 evaluates a conditional write (`If-None-Match: *`, `If-Match`) atomically with
the write, and skybake's leases rely on that (at most one replica wins the create). moto checks the
condition and then stores the object in two steps; with moto's own threaded server two concurrent
creates of the same lease can both pass the check, and two replicas then compute the same product.
Holding one lock over each request restores S3's atomicity (the requests stay concurrent on the
wire: a slow client does not block the others until its request has been read).

Usage: `python3 tools/s3_test_server.py --port PORT [--host ADDR] [--bucket NAME]` (prints `ready`
once the bucket exists and the server listens). `deploy/compose.yaml` runs it as its S3 server.
"""

import argparse
import threading

from moto.moto_server.werkzeug_app import DomainDispatcherApplication, create_backend_app
from werkzeug.serving import make_server


class OneAtATime:
    """WSGI middleware: each request is read, handled and its response body built under one lock."""

    def __init__(self, app):
        self.app = app
        self.lock = threading.Lock()

    def __call__(self, environ, start_response):
        with self.lock:
            captured = {}

            def capture(status, headers, exc_info=None):
                captured["args"] = (status, headers, exc_info)
                return lambda _data: None

            body = self.app(environ, capture)
            try:
                chunks = list(body)
            finally:
                close = getattr(body, "close", None)
                if close is not None:
                    close()
        status, headers, exc_info = captured["args"]
        start_response(status, headers, exc_info)
        return chunks


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--bucket", default="skybake-test")
    args = parser.parse_args()

    app = DomainDispatcherApplication(create_backend_app)
    server = make_server(args.host, args.port, OneAtATime(app), threaded=True)

    # The bucket, created through the server itself (as a client would), before `ready`.
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    import boto3

    local = "127.0.0.1" if args.host in ("0.0.0.0", "::", "") else args.host
    s3 = boto3.client(
        "s3",
        endpoint_url=f"http://{local}:{args.port}",
        region_name="us-east-1",
        aws_access_key_id="skybake-test",
        aws_secret_access_key="skybake-test",
    )
    s3.create_bucket(Bucket=args.bucket)
    print("ready", flush=True)
    thread.join()


if __name__ == "__main__":
    main()
