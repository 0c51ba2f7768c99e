"""`make run`: write two demo photos, serve the screening API on :8000 and screen both."""

from __future__ import annotations

import errno
import json
import socket
import sys
import threading
import time
from pathlib import Path

HOST, PORT = "127.0.0.1", 8000
DEMO_DIR = Path("demo")


def _port_free(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                return False
            raise
    return True


def _screen_both(server, base: str, paths: list[Path]) -> None:
    import httpx

    while not server.started and not server.should_exit:
        time.sleep(0.05)
    if server.should_exit:
        return
    with httpx.Client(base_url=base, timeout=60.0) as client:
        for path in paths:
            with path.open("rb") as fh:
                r = client.post("/v1/screen", files={"file": (path.name, fh, "image/jpeg")})
            print(f"\n# {path} -> HTTP {r.status_code}")
            print(json.dumps(r.json(), indent=2))
    print(f"\nServing on {base} (docs: {base}/docs). Press Ctrl-C to stop.", flush=True)


def main() -> int:
    """Write demo images, start the service, screen both images over HTTP, keep serving."""
    import uvicorn

    from service.app import create_app
    from service.settings import ServiceSettings
    from synth import demo_images

    if not _port_free(HOST, PORT):
        print(f"error: port {PORT} on {HOST} is already in use; stop whatever is listening "
              f"there (e.g. `lsof -i :{PORT}`) or run `lishield-guard serve --port 8001`.",
              file=sys.stderr)
        return 1
    print(f"Writing demo images to {DEMO_DIR}/ ...", flush=True)
    protected, clean = demo_images(DEMO_DIR, seed=0)
    base = f"http://{HOST}:{PORT}"
    print("\nScreen them yourself with:")
    for path in (protected, clean):
        print(f"  curl -s -F file=@{path} {base}/v1/screen")
    print(f"  curl -s --data-binary @{protected} '{base}/v1/screen?explain=true'")
    print(f"  curl -s {base}/v1/policies ; curl -s {base}/metrics\n", flush=True)
    server = uvicorn.Server(uvicorn.Config(create_app(ServiceSettings()), host=HOST, port=PORT,
                                           access_log=False, log_level="warning"))
    threading.Thread(target=_screen_both, args=(server, base, [protected, clean]),
                     daemon=True).start()
    server.run()
    return 0


if __name__ == "__main__":
    sys.exit(main())
