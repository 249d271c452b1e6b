"""A real HTTP server on 127.0.0.1 for the download tests (weights, hub models)."""

import http.server
import threading


class LocalServer:
    """``handler`` (a BaseHTTPRequestHandler class) served from a thread; ``base`` is its URL."""

    def __init__(self, handler) -> None:
        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()
        self.base = f"http://127.0.0.1:{self.httpd.server_address[1]}"

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()
