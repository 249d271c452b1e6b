"""Weights fetched once, resumed, checked: against a real HTTP server on 127.0.0.1."""

import hashlib
import http.server
import socket

import pytest

from masks.checkpoints import Checkpoint, fetch, sam_checkpoint
from masks.generators.base import MaskError
from tests.masks.local_server import LocalServer

BODY = bytes(range(256)) * 64  # 16 KiB
SHA = hashlib.sha256(BODY).hexdigest()


class _Server:
    """Serves BODY at /w/model_abc.pth, honouring Range unless told not to; can cut the
    connection after ``cut`` bytes; records the Range headers it saw."""

    def __init__(self):
        self.ranges, self.cut, self.honour_range, self.requests = [], None, True, 0
        srv = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self):
                srv.requests += 1
                rng = self.headers.get("Range")
                srv.ranges.append(rng)
                start = int(rng.split("=")[1].rstrip("-")) if rng and srv.honour_range else 0
                body = BODY[start:]
                self.send_response(206 if start else 200)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                if srv.cut is not None:
                    self.wfile.write(body[: srv.cut])
                    self.wfile.flush()
                    self.connection.shutdown(socket.SHUT_RDWR)
                    return
                self.wfile.write(body)

            def log_message(self, *args):
                pass

        self.server = LocalServer(Handler)
        self.url = f"{self.server.base}/w/model_abc.pth"

    def close(self):
        self.server.close()


@pytest.fixture
def server():
    s = _Server()
    yield s
    s.close()


def test_fetch_downloads_checks_and_reuses(server, tmp_path):
    path = fetch(Checkpoint(server.url, SHA), tmp_path, progress=False)
    assert path == tmp_path / "model_abc.pth" and path.read_bytes() == BODY
    assert not (tmp_path / "model_abc.pth.part").exists()
    assert fetch(Checkpoint(server.url, SHA), tmp_path, progress=False) == path and server.requests == 1  # reused


def test_a_broken_download_resumes_with_a_range_request(server, tmp_path):
    server.cut = 5000
    with pytest.raises(MaskError, match=r"connection ended after 5000 of 16384 bytes; run again to resume"):
        fetch(Checkpoint(server.url, SHA), tmp_path, progress=False)
    assert (tmp_path / "model_abc.pth.part").stat().st_size == 5000 and not (tmp_path / "model_abc.pth").exists()
    server.cut = None
    path = fetch(Checkpoint(server.url, SHA), tmp_path, progress=True)  # with the progress bar
    assert path.read_bytes() == BODY and server.ranges[-1] == "bytes=5000-"


def test_a_server_ignoring_the_range_gives_a_fresh_download(server, tmp_path):
    (tmp_path / "model_abc.pth.part").write_bytes(b"stale bytes")
    server.honour_range = False
    assert fetch(Checkpoint(server.url, SHA), tmp_path, progress=False).read_bytes() == BODY


def test_wrong_checksum_and_no_network_are_one_line_errors(server, tmp_path):
    with pytest.raises(MaskError, match=r"model_abc.pth: downloaded file has SHA-256 [0-9a-f]{12}\.\.\., not the published 000000000000"):
        fetch(Checkpoint(server.url, "0" * 64), tmp_path, progress=False)
    assert list(tmp_path.iterdir()) == []  # nothing half-written left behind
    (tmp_path / "model_abc.pth").write_bytes(b"not the model")
    with pytest.raises(MaskError, match="model_abc.pth: SHA-256 .* is not the published .*; delete it"):
        fetch(Checkpoint(server.url, SHA), tmp_path, progress=False)
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(MaskError, match=r"cannot download .*masks.checkpoint=PATH"):
        fetch(Checkpoint(f"http://127.0.0.1:{port}/x.pth", SHA), tmp_path / "other", progress=False)
    with pytest.raises(MaskError, match=r"masks.model=vit_x: choose vit_b, vit_l, vit_h"):
        sam_checkpoint("vit_x")


def test_masks_model_fetches_the_official_checkpoint_for_the_sam_generator(server, tmp_path, monkeypatch):
    import masks.checkpoints as ck
    from benchmark.config import ConfigError
    from benchmark.pipeline.masks import make_mask_generator
    from benchmark.pipeline.settings import MaskSettings, recorded_masks

    monkeypatch.setenv("TRASE_BENCH_CACHE", str(tmp_path))
    monkeypatch.setitem(ck.SAM_CHECKPOINTS, "vit_b", Checkpoint(server.url, SHA))
    gen = make_mask_generator(MaskSettings(generator="sam", model="vit_b"))
    assert gen.checkpoint == tmp_path / "weights" / "model_abc.pth" and gen.model_type == "vit_b"
    with pytest.raises(ConfigError, match="masks.model=vit_b|vit_l|vit_h"):
        make_mask_generator(MaskSettings(generator="sam"))
    with pytest.raises(ConfigError, match="--set masks.model=vit_q: choose"):
        MaskSettings(generator="sam", model="vit_q")
    # a run that names no model keeps the record (and so the hash) it had before the setting
    assert "model" not in recorded_masks({"generator": "classical", "checkpoint": None, "seed": 0, "model": None})
