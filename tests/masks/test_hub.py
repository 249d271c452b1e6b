"""Model folders fetched once from a hub: against a real HTTP server on 127.0.0.1 that answers
the hub's API (revision, file tree with checksums) and serves the files."""

import hashlib
import http.server
import json

import pytest

pytest.importorskip("huggingface_hub")

from masks.hub import hub_folder, model_folder
from masks.maskset import MaskError
from tests.masks.local_server import LocalServer

COMMIT = "0123456789abcdef0123456789abcdef01234567"
FILES = {"config.json": b'{"model_type": "tiny"}', "model.safetensors": bytes(range(256)) * 40,
         "README.md": b"not a model file"}
LFS = {"model.safetensors"}  # large files: the hub publishes their SHA-256


def _blob_sha1(data: bytes) -> str:
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()


class Hub:
    def __init__(self):
        self.files, self.requests, self.tamper = dict(FILES), [], {}
        hub = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self):
                hub.requests.append(self.path)
                if self.path.startswith("/api/models/owner/tiny/tree/"):
                    body = json.dumps([hub.entry(name) for name in hub.files]).encode()
                elif self.path.startswith("/api/models/owner/tiny"):
                    body = json.dumps({"id": "owner/tiny", "sha": COMMIT}).encode()
                elif self.path.startswith(f"/owner/tiny/resolve/{COMMIT}/"):
                    name = self.path.rsplit("/", 1)[1]
                    body = hub.tamper.get(name, hub.files.get(name))
                else:
                    body = None
                if body is None:
                    self.send_response(404)
                    self.end_headers()
                    return
                self.send_response(200)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args):
                pass

        self.server = LocalServer(Handler)
        self.url = self.server.base

    def entry(self, name):
        data = self.files[name]
        e = {"type": "file", "path": name, "size": len(data), "oid": _blob_sha1(data)}
        if name in LFS:
            e["lfs"] = {"oid": hashlib.sha256(data).hexdigest(), "size": len(data), "pointerSize": 130}
        return e

    def close(self):
        self.server.close()


@pytest.fixture
def hub():
    h = Hub()
    yield h
    h.close()


def test_a_hub_model_is_fetched_once_checked_and_then_used_offline(hub, tmp_path):
    folder = hub_folder("owner/tiny", tmp_path, endpoint=hub.url, progress=False)
    assert folder == tmp_path / "owner--tiny"
    assert (folder / "model.safetensors").read_bytes() == FILES["model.safetensors"]
    assert not (folder / "README.md").exists()  # only what a model folder needs
    record = json.loads((folder / "files.json").read_text())
    assert {r["name"]: r["digest"] for r in record} == {"config.json": "git-sha1", "model.safetensors": "sha256"}
    hub.close()  # no network: the record and the checked files are enough
    assert model_folder("owner/tiny", tmp_path, endpoint=hub.url, progress=False) == folder


def test_a_file_that_is_not_the_published_one_is_never_kept(hub, tmp_path):
    hub.tamper["model.safetensors"] = b"x" * 100
    with pytest.raises(MaskError, match=r"model.safetensors: downloaded file has SHA-256 [0-9a-f]{12}\.\.\., not the "
                                        r"published [0-9a-f]{12}\.\.\."):
        hub_folder("owner/tiny", tmp_path, endpoint=hub.url, progress=False)
    assert not (tmp_path / "owner--tiny" / "files.json").exists()
    assert not (tmp_path / "owner--tiny" / "model.safetensors").exists()
    hub.tamper.clear()
    folder = hub_folder("owner/tiny", tmp_path, endpoint=hub.url, progress=False)  # the next try fetches it
    (folder / "config.json").write_text("{}")  # changed in the cache afterwards: refused at the next use
    with pytest.raises(MaskError, match=r"config.json: git blob SHA-1 .* is not the published .*; delete it"):
        hub_folder("owner/tiny", tmp_path, endpoint=hub.url, progress=False)


def test_a_repository_without_a_config_and_an_unreachable_hub_are_one_line_errors(hub, tmp_path):
    del hub.files["config.json"]
    with pytest.raises(MaskError, match=r"owner/tiny: the repository has no config.json at its top level"):
        hub_folder("owner/tiny", tmp_path, endpoint=hub.url, progress=False)
    hub.close()
    with pytest.raises(MaskError, match=r"^http://127.0.0.1:\d+/owner/tiny: cannot list the model's files \(.*\); "
                                        r"with no network, download the folder elsewhere and pass its path$"):
        hub_folder("owner/tiny", tmp_path / "again", endpoint=hub.url, progress=False)
