"""parsedit.php's wire format, without a camera: query strings in, XML out."""

import pytest

from elphel_sim.stock.parsedit import (
    ParseditQuery,
    UnknownParameterError,
    Write,
    parameters_xml,
    parse_query,
    php_intval,
    unknown_name_xml,
)

KNOWN = frozenset({"EXPOS", "WOI_WIDTH", "FRAME", "SENSOR", "GAINR"})


@pytest.mark.parametrize(
    ("text", "value"),
    [
        ("5000", 5000),
        ("0x1F", 31),
        ("0X10", 16),
        ('"42"', 42),
        ("12abc", 12),
        ("abc", 0),
        ("", 0),
        ("-7", -7),
        (" 8 ", 8),
        ("0x", 0),
    ],
)
def test_numbers_are_read_as_php_intval_reads_them(text, value):
    assert php_intval(text) == value


def test_reads_and_writes_with_default_ahead():
    q = parse_query("immediate&sensor_port=1&EXPOS=5000&WOI_WIDTH&FRAME", known=KNOWN)
    assert q == ParseditQuery(
        immediate=True,
        sensor_port=1,
        names=("EXPOS", "WOI_WIDTH", "FRAME"),
        writes=(Write("EXPOS", 5000, 3),),
    )


def test_ahead_mask_and_chained_values():
    q = parse_query("immediate&EXPOS=5000*5:6000*7!3&GAINR=0x20000!5", known=KNOWN)
    assert q.writes == (
        Write("EXPOS", 5000, 5),
        Write("EXPOS", 6000, 7, 3),
        Write("GAINR", 0x20000, 3, 5),
    )


def test_read_only_monitor_empty_value_and_negative_ahead():
    q = parse_query("immediate&EXPOS=@&WOI_WIDTH=&FRAME=*4&GAINR=70000*-2", known=KNOWN)
    assert q.names == ("EXPOS", "WOI_WIDTH", "FRAME", "GAINR")
    assert q.writes == (Write("GAINR", 70000, 0),)


def test_percent_encoding_sensor_port_mask_and_repeated_keys():
    q = parse_query("immediate&sensor_port=6&EXPOS=1000%2A4%214&EXPOS=2000", known=KNOWN)
    assert q.sensor_port == 2  # the script keeps the two low bits
    assert q.writes == (Write("EXPOS", 2000, 3),)  # the last value of a key wins
    assert parse_query("EXPOS", known=KNOWN).immediate is False


def test_an_unknown_name_is_refused_before_anything_is_written():
    with pytest.raises(UnknownParameterError, match="'EXPOSURE'") as e:
        parse_query("immediate&EXPOS=5000&EXPOSURE=1", known=KNOWN)
    assert e.value.name == "EXPOSURE"


def test_answers_byte_for_byte():
    assert parameters_xml({"EXPOS": 5000, "FRAME": 17}) == (
        b'<?xml version="1.0"?>\n<parameters>\n  <EXPOS>5000</EXPOS>\n'
        b"  <FRAME>17</FRAME>\n</parameters>\n"
    )
    assert unknown_name_xml("FOO") == (
        b'<?xml version="1.0"?>\n<framepars><ERROR>"Wrong address==0, probably '
        b"misspelled constant: 'FOO'\"</ERROR></framepars>\n"
    )
    assert b"&lt;b&gt;" in unknown_name_xml("<b>")
