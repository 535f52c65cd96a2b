"""A burst that breaks off: the host client raises and keeps the complete pages it got."""

import json

import httpx
import numpy as np
import pytest
import tifffile

from elphel_camd.api import tiff
from elphel_host.camera import cli as camera_cli
from elphel_host.camera.client import CameraClient, PartialBurstError
from elphel_host.cli import main


def burst_bytes(count: int) -> bytes:
    pages = [
        (np.full((6, 8), k, dtype=np.uint16), {"frame": 40 + k, "port": 0, "WOI_WIDTH": 8})
        for k in range(count)
    ]
    return b"".join(bytes(c) for c in tiff.stream(iter(pages), count))


class Broken(httpx.SyncByteStream):
    """A body that ends with a transport error after ``keep`` bytes (a broken-off burst)."""

    def __init__(self, data: bytes, keep: int) -> None:
        self.data, self.keep = data, keep

    def __iter__(self):
        yield self.data[: self.keep]
        raise httpx.RemoteProtocolError("peer closed connection without sending complete body")


def broken_client(count: int = 4, pages_sent: int = 2) -> CameraClient:
    whole = burst_bytes(count)
    page_bytes = (len(whole) - 8) // count
    keep = 8 + pages_sent * page_bytes + page_bytes // 2  # two pages and half of the third

    def handler(request: httpx.Request) -> httpx.Response:
        assert request.url.params["count"] == str(count)
        return httpx.Response(
            200,
            headers={"content-type": "image/tiff", "x-frame-count": str(count)},
            stream=Broken(whole, keep),
        )

    return CameraClient("http://camera:8000", "t", transport=httpx.MockTransport(handler))


def test_broken_burst_raises_with_the_complete_pages():
    with broken_client() as cam, pytest.raises(PartialBurstError, match="after 2 of 4") as e:
        cam.burst(4)
    partial = e.value.partial
    assert not partial.complete
    assert [m["frame"] for m in partial.metadata] == [40, 41]
    assert [int(im[0, 0]) for im in partial.images] == [0, 1]
    with tifffile.TiffFile(__import__("io").BytesIO(partial.tiff)) as tif:
        assert len(tif.pages) == 2
        assert json.loads(tif.pages[1].description)["frame"] == 41


def test_cli_keep_partial_writes_the_frames_received(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(camera_cli, "connect", lambda url, token: broken_client())
    out = tmp_path / "b.tif"
    args = ["camera", "capture", "--camera", "http://camera:8000", "--count", "4"]
    assert main([*args, "--out", str(out)]) != 0
    assert not out.exists()
    assert "burst ended after 2 of 4" in capsys.readouterr().err
    assert main([*args, "--out", str(out), "--keep-partial"]) == 1
    assert "kept frames 40..41" in capsys.readouterr().err
    with tifffile.TiffFile(out) as tif:
        assert [json.loads(p.description)["frame"] for p in tif.pages] == [40, 41]
