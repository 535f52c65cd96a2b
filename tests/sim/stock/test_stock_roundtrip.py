"""Frames served by the simulated stock NC393, decoded by the host (elphel_host.camera.jp4).

The simulator's compressor and the host's decoder are separate code: a frame taken
through imgsrv and decoded must be the frame the sensor read out, with the metadata an
elphel-camd capture of that frame has.
"""

import numpy as np
import pytest

from elphel_host.camera.jp4 import decode_frame

LINEAR = "GTAB_R=0x00640400&GTAB_G=0x00640400&GTAB_GB=0x00640400&GTAB_B=0x00640400"


def take(web, imgsrv, firmware, query: str):
    web.get(f"/parsedit.php?immediate&{query}")
    assert firmware.wait_frame(0, firmware.frame(0) + 4)
    r = imgsrv[0].get("/towp/wait/bimg")
    image, meta = decode_frame(r.content, r.headers["content-type"])
    got, camd = firmware.service.capture(0, frame=meta["frame"])
    return image, meta, got.image, camd


@pytest.mark.parametrize("flips", ["FLIPH=0&FLIPV=0", "FLIPH=1&FLIPV=0", "FLIPH=1&FLIPV=1"])
@pytest.mark.parametrize("color", [5, 2])
def test_jp4_and_jp46_decode_to_the_read_out_frame(web, imgsrv, firmware, color, flips):
    image, meta, raw, camd = take(web, imgsrv, firmware, f"COLOR={color}&{LINEAR}&{flips}")
    assert image.shape == raw.shape == (128, 256)
    for key in ("frame", "port", "bayer", "FLIPH", "FLIPV", "WOI_WIDTH"):
        assert meta[key] == camd[key], key
    assert meta["timestamp_ns"] == camd["timestamp_ns"] // 1000 * 1000  # Exif: microseconds
    assert abs(meta["EXPOS"] - camd["EXPOS"]) <= 1
    # Gamma 1, quality 100: the 8-bit code's half step plus at most one code of JPEG
    # rounding (1/256 of full scale each), and most samples within half a step.
    error = np.abs(image / 65535.0 - raw / 4096.0) * 256
    print(f"COLOR={color} {flips}: max {error.max():.3f} median {np.median(error):.3f} codes")
    assert error.max() <= 1.51  # (the decoder scales to 65535, the sensor to 65536)
    assert np.median(error) < 0.5


def test_raw_tiff_decodes_to_the_read_out_frame(web, imgsrv, firmware):
    image, meta, raw, camd = take(web, imgsrv, firmware, "COLOR=15")
    assert np.array_equal(image, raw)
    for key in ("frame", "port", "WOI_WIDTH", "GAINR"):
        assert meta[key] == camd[key], key
    assert meta["timestamp_ns"] == camd["timestamp_ns"] // 1000 * 1000
