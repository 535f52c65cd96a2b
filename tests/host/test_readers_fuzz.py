"""Property-based tests of the file readers and line parsers with random and mutated input.

Each reader either works or raises the project's typed error, with a message naming the
file (or the stream) and the field; no other exception escapes (no KeyError, TypeError,
AttributeError, RecursionError ... from deep inside). Examples are bounded and the runs
derandomized, so a failure reproduces.
"""

from __future__ import annotations

import contextlib
import json
import tempfile
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from elphel_camd.config import ConfigError, load_settings
from elphel_host.burst.manifest import read_manifest
from elphel_host.camera.events import SSEParser
from elphel_host.errors import ElphelError, InputFormatError, StageProtocolError
from elphel_host.stage.protocol import parse_reply, parse_status, seal, unseal
from elphel_host.tp.io import QuadManifest

FUZZ = settings(
    max_examples=150,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)

scalars = st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.text(max_size=12)
scalars |= st.floats(allow_nan=False, allow_infinity=False) | st.sampled_from([0, 1, -1, ""])
json_values = st.recursive(
    scalars,
    lambda inner: (
        st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=10), inner, max_size=5)
    ),
    max_leaves=25,
)

VALID_BURST = {
    "version": 1,
    "bayer": "GRBG",
    "frames": [
        {"file": "frames/0000.tif", "frame": 10, "timestamp_ns": 1, "stage_mm": 0.0},
        {"file": "frames/0001.tif", "frame": 11, "timestamp_ns": 2, "stage_mm": 0.01},
    ],
    "optics": {"focal_length_mm": 4.5, "pixel_pitch_um": 2.2, "object_distance_mm": 500.0},
    "stage": {"mm_per_step": 0.001, "axis_angle_deg": 0.0},
}
VALID_QUAD = {
    "version": 1,
    "cameras": [
        {"file": f"cam{i}.tif", "position": [float(i % 2), float(i // 2)]} for i in range(4)
    ],
}


def mutate(doc: Any, path: list[Any], value: Any) -> Any:
    """``doc`` with the element at ``path`` (indices taken modulo) replaced by ``value``."""
    if not path or not isinstance(doc, (dict, list)) or not doc:
        return value
    if isinstance(doc, dict):
        keys = sorted(doc)
        key = keys[path[0] % len(keys)] if isinstance(path[0], int) else path[0]
        return {**doc, key: mutate(doc.get(key), path[1:], value)}
    i = path[0] % len(doc) if isinstance(path[0], int) else 0
    return [*doc[:i], mutate(doc[i], path[1:], value), *doc[i + 1 :]]


paths = st.lists(st.integers(0, 7), min_size=1, max_size=4)
documents = st.one_of(
    json_values,
    st.builds(mutate, st.just(VALID_BURST), paths, json_values),
    st.builds(mutate, st.just(VALID_QUAD), paths, json_values),
)


def write(directory: Path, name: str, content: str | bytes) -> Path:
    path = directory / name
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    return path


def as_text(doc: Any) -> str:
    return json.dumps(doc, allow_nan=True)


raw_files = st.one_of(
    documents.map(as_text),
    st.binary(max_size=64),
    st.text(max_size=64),
    documents.map(as_text).map(lambda t: t[: len(t) // 2]),  # truncated
)


@FUZZ
@given(content=raw_files)
def test_burst_manifest_reader_works_or_names_the_file(content):
    with tempfile.TemporaryDirectory() as tmp:
        path = write(Path(tmp), "manifest.json", content)
        try:
            manifest = read_manifest(tmp)
        except InputFormatError as e:
            assert str(path) in str(e)
        else:
            assert manifest is not None and len(manifest.frames) >= 0


@FUZZ
@given(content=raw_files)
def test_quad_manifest_reader_works_or_names_the_file(content):
    with tempfile.TemporaryDirectory() as tmp:
        path = write(Path(tmp), "quad.json", content)
        try:
            QuadManifest.read(tmp)
        except InputFormatError as e:
            assert str(path) in str(e)


@FUZZ
@given(content=raw_files)
def test_daemon_config_reader_works_or_names_the_file(content):
    with tempfile.TemporaryDirectory() as tmp:
        path = write(Path(tmp), "config.json", content)
        try:
            load_settings(path)
        except ConfigError as e:
            assert str(path) in str(e)


stage_lines = st.one_of(
    st.text(max_size=40),
    st.text(alphabet="OKERSTAUPOSVL=,;*0123456789ABCDEF -.", max_size=40),
    st.text(max_size=30).map(seal),
    st.builds(
        lambda a, b: seal(f"{a} {b}"),
        st.sampled_from(["OK", "ERR", "STATUS"]),
        st.text(max_size=20),
    ),
)


@FUZZ
@given(line=stage_lines)
def test_stage_line_protocol_parses_or_raises_stage_protocol_errors(line):
    try:
        body = unseal(line)
    except StageProtocolError as e:
        assert repr(line) in str(e) or "checksum" in str(e)
        return
    with contextlib.suppress(StageProtocolError):
        parse_reply(body)
    with contextlib.suppress(StageProtocolError):
        parse_status(body)


sse_lines = st.lists(
    st.one_of(
        st.just(""),
        st.text(max_size=20),
        st.builds(lambda t: f"event: {t}", st.text(max_size=10)),
        st.builds(lambda t: f"data: {t}", st.text(max_size=20) | documents.map(as_text)),
        st.builds(lambda t: f"id: {t}", st.text(max_size=8) | st.integers(0, 99).map(str)),
        st.just(": keepalive"),
    ),
    max_size=12,
)


@FUZZ
@given(lines=sse_lines)
def test_sse_parser_gives_events_or_a_typed_error_naming_the_event(lines):
    parser = SSEParser()
    for line in lines:
        try:
            event = parser.feed(line)
        except ElphelError as e:
            assert "data" in str(e)
            parser = SSEParser()
            continue
        if event is not None:
            assert isinstance(event.type, str) and isinstance(event.data, dict)
            assert event.id is None or event.id >= 0


# -- DSI / ML_DATA TIFFs and the stage model ----------------------------------------------------


def _ml_seed() -> bytes:
    import io

    import numpy as np
    import tifffile

    from elphel_host.tp.dsi import ML_LAYERS, properties_xml

    side = 3
    data = np.arange(len(ML_LAYERS) * (2 * side) ** 2, dtype=np.float32)
    buf = io.BytesIO()
    tifffile.imwrite(
        buf,
        data.reshape(len(ML_LAYERS), 2 * side, 2 * side),
        imagej=True,
        metadata={"Labels": list(ML_LAYERS), "Info": properties_xml({"tileWidth": side})},
    )
    return buf.getvalue()


ML_SEED = _ml_seed()


def _mutated(seed: bytes, edits: list[tuple[int, int]], cut: int | None) -> bytes:
    out = bytearray(seed)
    for at, value in edits:
        out[at % len(out)] = value
    return bytes(out[:cut] if cut is not None else out)


tiffs = st.builds(
    _mutated,
    st.just(ML_SEED),
    st.lists(st.tuples(st.integers(0, 2**16), st.integers(0, 255)), max_size=6),
    st.none() | st.integers(0, len(ML_SEED)),
)


@FUZZ
@given(content=tiffs | st.binary(max_size=64))
def test_dsi_and_ml_data_readers_work_or_name_the_file(content):
    from elphel_host.tp.dsi import read_dsi, read_ml_data

    with tempfile.TemporaryDirectory() as tmp:
        path = write(Path(tmp), "ml.tiff", content)
        for reader in (read_dsi, read_ml_data):
            try:
                reader(path)
            except InputFormatError as e:
                assert str(path) in str(e)


def test_the_unmutated_ml_data_seed_reads():
    from elphel_host.tp.dsi import read_ml_data

    with tempfile.TemporaryDirectory() as tmp:
        corr, other, _props = read_ml_data(write(Path(tmp), "ml.tiff", ML_SEED))
    assert corr.shape == (2, 2, 3, 3, 4) and other.shape == (2, 2, 3)


STAGE_MODEL = {"mm_per_step": 0.00125, "offset_mm": 1.5, "backlash_mm": 0.01}


@FUZZ
@given(
    content=st.one_of(
        raw_files,
        st.builds(mutate, st.just(STAGE_MODEL), paths, json_values).map(as_text),
    )
)
def test_stage_model_reader_works_or_names_the_file(content):
    from elphel_host.stage.model import StageModel

    with tempfile.TemporaryDirectory() as tmp:
        path = write(Path(tmp), "stage.json", content)
        try:
            model = StageModel.load(path)
        except InputFormatError as e:
            assert str(path) in str(e)
        else:
            assert model.mm_per_step > 0 and model.calibrated
