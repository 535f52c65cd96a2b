"""The decoder on hand-built frames: Exif transcripts, bad inputs, raw TIFFs, content types.

Each bad input gives one `Jp4FormatError` (an `InputFormatError`) whose one-line message
says what is wrong.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile

from elphel_host.camera.exif import ExifFields, read_exif, scan_jpeg
from elphel_host.camera.jp4 import decode_frame, decode_jp4, decode_tiff
from elphel_host.camera.makernote import MakerNote, code_positions, linear_lut
from elphel_host.errors import InputFormatError, Jp4FormatError
from elphel_sim.jp4 import encode_jp4

from .frames import (
    ASCII,
    LONG,
    SHORT,
    UNDEFINED,
    elphel_exif,
    greyscale_jpeg,
    maker_note,
    raw_tiff,
    tiff_structure,
    with_exif,
)

T0 = 1_700_000_000_000_000_000


def test_exif_transcript_big_endian() -> None:
    block = elphel_exif(maker_note(), frame=123456)
    assert read_exif(block) == ExifFields(
        make="Elphel",
        model="NC393",
        image_number=123456,
        page_number=1,
        exposure_time=(2500, 1_000_000),
        date_time_original="2024:05:06 07:08:09",
        subsec_time_original="250000",
        maker_note=maker_note(),
    )


def test_exif_little_endian_and_byte_maker_note() -> None:
    words = maker_note(words=12)
    note_bytes = b"".join(w.to_bytes(4, "little") for w in words)
    block = tiff_structure(
        [(0x9211, LONG, (7,)), (0x0129, SHORT, (2,))],
        [(0x927C, UNDEFINED, note_bytes)],
        order="<",
    )
    fields = read_exif(block)
    assert (fields.image_number, fields.page_number, fields.maker_note) == (7, 2, words)
    assert fields.date_time_original is None


def test_metadata_from_a_hand_built_frame() -> None:
    data = with_exif(greyscale_jpeg(64, 32), elphel_exif(maker_note(flips=3)))
    image, meta = decode_jp4(data)
    assert image.shape == (32, 64) and image.dtype == np.uint16
    assert meta["frame"] == 9 and meta["port"] == 1 and meta["EXPOS"] == 2500
    assert meta["timestamp_ns"] == 1_714_979_289_250_000_000  # 2024-05-06T07:08:09.25Z
    assert meta["bayer"] == "GBRG" and (meta["FLIPH"], meta["FLIPV"]) == (1, 1)
    assert (meta["WOI_WIDTH"], meta["WOI_HEIGHT"]) == (64, 32)


def test_older_twelve_word_maker_note_has_no_quality() -> None:
    data = with_exif(greyscale_jpeg(), elphel_exif(maker_note(words=12)))
    assert decode_jp4(data)[1]["quality"] is None


def test_inverse_gamma_hits_each_codes_centre() -> None:
    p = code_positions(1.0, 0.0, 0x400)
    # linear table: entries round(65535 i / 256), i.e. 0, 256, ..., 65279, 65535
    assert p[0] == 0.5  # 128 of the 256 between entries 0 and 1
    assert p[255] == 255 + (65408 - 65279) / 256
    assert p[100] == pytest.approx(100.5)
    lut = linear_lut(0.57, 10 / 256, 0x400)
    assert lut.dtype == np.uint16 and lut.shape == (256,) and not lut.flags.writeable
    assert np.all(np.diff(lut.astype(int)) > 0)
    assert code_positions(0.57, 10 / 256, 0x400)[0] > 10  # above the black level


def _error(data: bytes) -> str:
    with pytest.raises(Jp4FormatError) as info:
        decode_jp4(data)
    assert isinstance(info.value, InputFormatError)
    message = str(info.value)
    assert "\n" not in message
    return message


def _frame(**kwargs: object) -> bytes:
    mosaic = np.full((32, 64), 1000, dtype=np.uint16)
    return encode_jp4(mosaic, bits=12, frame=1, timestamp_ns=T0, **kwargs)  # type: ignore[arg-type]


def test_not_a_jpeg() -> None:
    assert _error(b"GIF89a\x01\x00") == "not a JPEG: starts with 47494638"
    assert _error(b"") == "not a JPEG: starts with nothing"


def test_truncated_jpeg_in_the_scan_data() -> None:
    rng = np.random.default_rng(1)
    mosaic = rng.integers(0, 4096, (64, 128)).astype(np.uint16)
    data = encode_jp4(mosaic, bits=12, frame=1, timestamp_ns=T0)
    assert _error(data[: len(data) - 200]).startswith("truncated JPEG: no end-of-image marker")


def test_truncated_jpeg_in_the_headers() -> None:
    data = _frame()
    message = _error(data[:60])
    assert message.startswith("truncated JPEG: segment FFE1 at byte 2 needs")


def test_no_exif() -> None:
    assert _error(greyscale_jpeg()).startswith("no Exif (APP1) block")


def test_missing_maker_note() -> None:
    message = _error(with_exif(greyscale_jpeg(), elphel_exif(None)))
    assert message.startswith("no MakerNote (Exif tag 0x927C)")


@pytest.mark.parametrize("words", [0, 8, 10])
def test_short_maker_note(words: int) -> None:
    note = maker_note(words=words) if words else ()
    message = _error(with_exif(greyscale_jpeg(), elphel_exif(note)))
    assert message == (
        f"short MakerNote: {words} words; need at least 11 (gains, gamma, window and colour mode)"
    )


def test_unknown_color_mode() -> None:
    message = _error(with_exif(greyscale_jpeg(), elphel_exif(maker_note(color_mode=7))))
    assert message == "unknown COLOR_MODE 7 in the MakerNote; allowed: 5 (JP4), 2 (JP46), 0 (mono)"


def test_width_not_a_multiple_of_32() -> None:
    message = _error(with_exif(greyscale_jpeg(48, 32), elphel_exif(maker_note())))
    assert message == "JP4 frame 48x32: width not a multiple of 32"


def test_height_not_a_multiple_of_16() -> None:
    message = _error(with_exif(greyscale_jpeg(64, 24), elphel_exif(maker_note(color_mode=2))))
    assert message == "JP46 frame 64x24: height not a multiple of 16"


def test_colour_jpeg_is_not_raw() -> None:
    message = _error(with_exif(greyscale_jpeg(mode="RGB"), elphel_exif(maker_note(color_mode=0))))
    assert message.startswith("3-component JPEG with COLOR_MODE 0: a colour JPEG")


def test_bad_date() -> None:
    block = elphel_exif(maker_note(), when="yesterday")
    message = _error(with_exif(greyscale_jpeg(), block))
    assert message == "Exif DateTimeOriginal='yesterday'; allowed: 'YYYY:MM:DD HH:MM:SS'"


def test_exif_pointer_outside_the_block() -> None:
    block = tiff_structure([(0x8769, LONG, (4000,))], None)
    message = _error(with_exif(greyscale_jpeg(), block))
    assert message.startswith("Exif: Exif IFD at offset 4000 lies outside the")


def test_maker_note_of_the_wrong_type() -> None:
    block = tiff_structure([], [(0x927C, ASCII, "hello")])
    message = _error(with_exif(greyscale_jpeg(), block))
    assert message.startswith("Exif: MakerNote of type 2; allowed: LONG words")


def test_scan_jpeg_reads_the_frame_header() -> None:
    info = scan_jpeg(_frame())
    assert (info.width, info.height, info.components) == (64, 32, 1)
    assert info.exif is not None and info.exif[:4] == b"MM\0\x2a"


def test_decode_frame_by_content_type() -> None:
    jp4 = _frame()
    assert decode_frame(jp4, "image/jp4")[1]["source"] == "jp4"
    assert decode_frame(jp4, "image/jpeg; charset=binary")[1]["COLOR"] == 5
    jp46 = _frame(color_mode=2)
    assert decode_frame(jp46, "image/jp46")[1]["source"] == "jp46"
    with pytest.raises(Jp4FormatError, match="content type image/jp46 but the MakerNote says"):
        decode_frame(jp4, "image/jp46")
    with pytest.raises(Jp4FormatError, match=r"content type 'text/html'; allowed: image/jp4"):
        decode_frame(b"<html>", "text/html")


def test_raw_16_bit_tiff_with_json_metadata() -> None:
    import io

    image = np.arange(32 * 64, dtype=np.uint16).reshape(32, 64)
    buf = io.BytesIO()
    tifffile.imwrite(buf, image, description=json.dumps({"frame": 5, "port": 2}), metadata=None)
    got, meta = decode_frame(buf.getvalue(), "image/tiff")
    assert np.array_equal(got, image)
    assert meta == {"frame": 5, "port": 2, "source": "tiff", "COLOR": 15}


def test_raw_16_bit_tiff_with_exif() -> None:
    image = (np.arange(16 * 32, dtype=np.uint16) * 97).reshape(16, 32)
    exif = [(0x927C, LONG, maker_note(flips=1)), (0x9003, ASCII, "2024:05:06 07:08:09")]
    got, meta = decode_tiff(raw_tiff(image, exif))
    assert np.array_equal(got, image)
    assert meta["bayer"] == "RGGB" and meta["COLOR"] == 15 and meta["source"] == "tiff"
    assert "gamma" not in meta  # 16-bit raw data bypass the gamma tables


def test_raw_8_bit_tiff_is_linearised_with_its_maker_note() -> None:
    codes = np.tile(np.arange(0, 256, 8, dtype=np.uint8), (16, 1))
    exif = [(0x927C, LONG, maker_note(gamma=57))]
    got, meta = decode_tiff(raw_tiff(codes, exif))
    note = MakerNote.from_words(maker_note(gamma=57))
    assert np.array_equal(got, linear_lut(0.57, 0.0, 0x400)[codes])
    assert meta["gamma"] == [0.57] * 4 and note.gamma == (0.57,) * 4


def test_raw_8_bit_tiff_without_maker_note() -> None:
    with pytest.raises(Jp4FormatError, match="8-bit raw TIFF without a MakerNote"):
        decode_tiff(raw_tiff(np.zeros((16, 32), np.uint8), None))


def test_not_a_tiff() -> None:
    with pytest.raises(Jp4FormatError, match="not a readable TIFF"):
        decode_frame(b"MM\0\x2a\0\0", "image/tiff")
