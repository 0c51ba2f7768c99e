"""`make run`: write two demo photos, serve the screening API and screen both over HTTP.

Usage: ``python scripts/demo.py [--host 127.0.0.1] [--port 8000]`` (``make run PORT=8001``).
Needs only the runtime dependencies (``pip install -e .``): the demo's own requests use the
standard library.
"""

from __future__ import annotations

import argparse
import errno
import json
import socket
import sys
import threading
import time
import urllib.error
import urllib.request
import uuid
from pathlib import Path

DEMO_DIR = Path("demo")


def _port_problem(host: str, port: int) -> str | None:
    """Why ``host:port`` cannot be listened on, or None when it can."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                return "it is already in use"
            return exc.strerror or str(exc)
    return None


def _post_file(url: str, path: Path) -> tuple[int, dict]:
    """POST ``path`` as multipart field ``file``; (status, JSON body)."""
    boundary = uuid.uuid4().hex
    body = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"file\"; "
            f"filename=\"{path.name}\"\r\nContent-Type: image/jpeg\r\n\r\n").encode()
    body += path.read_bytes() + f"\r\n--{boundary}--\r\n".encode()
    req = urllib.request.Request(url, data=body, method="POST", headers={
        "Content-Type": f"multipart/form-data; boundary={boundary}"})
    try:
        with urllib.request.urlopen(req, timeout=120) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read() or b"{}")


def _screen_both(server, base: str, paths: list[Path]) -> None:
    while not server.started and not server.should_exit:
        time.sleep(0.05)
    if server.should_exit:
        return
    for path in paths:
        status, body = _post_file(f"{base}/v1/screen", path)
        print(f"\n# {path} -> HTTP {status}")
        print(json.dumps(body, indent=2))
    print(f"\nServing on {base}. Reviewer page: {base}/review  API docs: {base}/docs\n"
          "Press Ctrl-C to stop.", flush=True)


def main(argv: list[str] | None = None) -> int:
    """Write demo images, start the service, screen both images over HTTP, keep serving."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--host", default="127.0.0.1", help="interface to bind (default 127.0.0.1)")
    ap.add_argument("--port", type=int, default=8000, help="TCP port (default 8000)")
    args = ap.parse_args(argv)
    host, port = args.host, args.port

    problem = _port_problem(host, port)
    if problem:
        print(f"error: cannot serve on {host}:{port}: {problem}. Run `make run PORT=8001` (or "
              f"any free port), or stop what is listening there (`lsof -i :{port}`).",
              file=sys.stderr)
        return 1

    import uvicorn

    from service.app import create_app
    from service.protocol import UVICORN_HTTP
    from service.settings import ServiceSettings
    from synth import demo_images

    print(f"Writing demo images to {DEMO_DIR}/ ...", flush=True)
    protected, clean = demo_images(DEMO_DIR, seed=0)
    base = f"http://{host}:{port}"
    print("\nScreen them yourself with:")
    for path in (protected, clean):
        print(f"  curl -s -F file=@{path} {base}/v1/screen")
    print(f"  curl -s --data-binary @{protected} '{base}/v1/screen?explain=true'")
    print(f"  curl -s -F file=@{protected} {base}/v1/screen/plot -o verdict.png")
    print(f"  open {base}/review in a browser and drop an image\n", flush=True)
    server = uvicorn.Server(uvicorn.Config(create_app(ServiceSettings()), host=host, port=port,
                                           access_log=False, log_level="warning",
                                           http=UVICORN_HTTP))
    threading.Thread(target=_screen_both, args=(server, base, [protected, clean]),
                     daemon=True).start()
    server.run()
    return 0


if __name__ == "__main__":
    sys.exit(main())
