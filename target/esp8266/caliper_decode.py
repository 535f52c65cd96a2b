# Caliper frames to micrometres. Pure logic, no hardware; runs under MicroPython and CPython.
#
# A frame is an int whose bit 0 is the first data bit clocked out (after any skipped
# start pulses). Every format is a dict of settings, so a caliper that differs from a
# preset is described in the board's JSON config instead of new code. Results are
# integer micrometres, rounded half away from zero; negative zero decodes to 0.


class CaliperDecodeError(ValueError):
    pass


# kind "binary": payload field, sign handling and an optional inch flag.
#   offset/width: where the signed payload sits in the frame; mag_bits and sign_bit are
#   relative to that field (sign mode "sm" = sign-magnitude; "ones"/"twos" use the
#   field's top bit). um_num/um_den: micrometres per count (metric); inch_num/inch_den
#   when the inch bit is set. zero_mask: frame bits that must read 0 (unused bits).
# kind "bcd7": six BCD digits LSD first, then a flag nibble.
# kind "digimatic": 13 nibbles, header 0xF x4, sign, 6 digits MSD first, point, unit.
PRESETS = {
    # Most cheap 0.01 mm calipers ("BIN6"): 20-bit magnitude, bit 20 sign, bit 23 inch.
    "bin6": {"kind": "binary", "bits": 24, "skip": 0, "offset": 0, "width": 24,
             "mag_bits": 20, "sign_bit": 20, "sign": "sm", "inch_bit": 23,
             "um_num": 10, "um_den": 1, "inch_num": 127, "inch_den": 10,
             "zero_mask": 0x600000, "negate": False, "clock": "device"},
    # Same frame read the sigrok way: 16-bit number, flags in the next 8 bits.
    "bin6_16": {"kind": "binary", "bits": 24, "skip": 0, "offset": 0, "width": 24,
                "mag_bits": 16, "sign_bit": 20, "sign": "sm", "inch_bit": 23,
                "um_num": 10, "um_den": 1, "inch_num": 127, "inch_den": 10,
                "zero_mask": 0x6F0000, "negate": False, "clock": "device"},
    # 48-bit "24BIT"/Sylvac burst: start pulse, word 1 absolute, word 2 = -display.
    # 20480 counts per inch. Sign convention is disputed, hence "sign" is a setting.
    "sylvac48": {"kind": "binary", "bits": 48, "skip": 1, "offset": 24, "width": 24,
                 "mag_bits": 23, "sign_bit": 23, "sign": "twos", "inch_bit": -1,
                 "um_num": 635, "um_den": 512, "inch_num": 635, "inch_den": 512,
                 "zero_mask": 0, "negate": True, "clock": "device"},
    "bcd7": {"kind": "bcd7", "bits": 28, "skip": 0, "neg_bit": 24, "half_bit": 25,
             "metric_bit": 27, "clock": "device"},
    # iGaging remote scales: host supplies the clock, 21-bit two's complement, 2560/in.
    "igaging21": {"kind": "binary", "bits": 21, "skip": 0, "offset": 0, "width": 21,
                  "mag_bits": 20, "sign_bit": 20, "sign": "twos", "inch_bit": -1,
                  "um_num": 635, "um_den": 64, "inch_num": 635, "inch_den": 64,
                  "zero_mask": 0, "negate": False, "clock": "host"},
    # Mitutoyo Digimatic: host pulls REQ, the gauge clocks out 52 bits.
    "digimatic": {"kind": "digimatic", "bits": 52, "skip": 0, "clock": "request"},
}

REQUIRED = {
    "binary": ("bits", "skip", "offset", "width", "mag_bits", "sign_bit", "sign",
               "inch_bit", "um_num", "um_den", "inch_num", "inch_den", "zero_mask",
               "negate", "clock"),
    "bcd7": ("bits", "skip", "neg_bit", "half_bit", "metric_bit", "clock"),
    "digimatic": ("bits", "skip", "clock"),
}


def make_format(name, overrides=None):
    """Return a format dict: preset `name` with `overrides` applied, checked."""
    if name not in PRESETS:
        raise CaliperDecodeError("caliper format %r unknown; allowed: %s"
                                 % (name, ", ".join(sorted(PRESETS))))
    fmt = dict(PRESETS[name])
    if overrides:
        for key in overrides:
            if key not in fmt:
                raise CaliperDecodeError("caliper setting %r not used by format %r; allowed: %s"
                                         % (key, name, ", ".join(sorted(fmt))))
            fmt[key] = overrides[key]
    check_format(fmt)
    return fmt


def check_format(fmt):
    kind = fmt.get("kind")
    if kind not in REQUIRED:
        raise CaliperDecodeError("caliper kind %r unknown; allowed: binary, bcd7, digimatic" % (kind,))
    for key in REQUIRED[kind]:
        if key not in fmt:
            raise CaliperDecodeError("caliper format lacks %r" % key)
    if fmt["clock"] not in ("device", "host", "request"):
        raise CaliperDecodeError("caliper clock %r; allowed: device, host, request" % (fmt["clock"],))
    if kind == "binary":
        if fmt["sign"] not in ("sm", "ones", "twos"):
            raise CaliperDecodeError("caliper sign %r; allowed: sm, ones, twos" % (fmt["sign"],))
        if fmt["offset"] + fmt["width"] > fmt["bits"]:
            raise CaliperDecodeError("caliper payload bits %d..%d exceed frame of %d bits"
                                     % (fmt["offset"], fmt["offset"] + fmt["width"] - 1, fmt["bits"]))
        if fmt["mag_bits"] > fmt["width"] or fmt["um_den"] <= 0 or fmt["inch_den"] <= 0:
            raise CaliperDecodeError("caliper mag_bits/width/scale inconsistent")


def _scale(count, num, den):
    # count * num / den rounded half away from zero, integers only (no single floats).
    if count < 0:
        return -((-count * num * 2 + den) // (2 * den))
    return (count * num * 2 + den) // (2 * den)


def _bit(frame, index):
    return (frame >> index) & 1


def decode(fmt, frame):
    """Decode one frame (int, bit 0 first clocked) to integer micrometres."""
    kind = fmt["kind"]
    if frame < 0 or frame >> fmt["bits"]:
        raise CaliperDecodeError("frame wider than %d bits" % fmt["bits"])
    if kind == "binary":
        return _decode_binary(fmt, frame)
    if kind == "bcd7":
        return _decode_bcd7(fmt, frame)
    return _decode_digimatic(frame)


def _decode_binary(fmt, frame):
    if frame & fmt["zero_mask"]:
        raise CaliperDecodeError("unused caliper bits set (mask 0x%X): glitch" % (frame & fmt["zero_mask"]))
    width = fmt["width"]
    field = (frame >> fmt["offset"]) & ((1 << width) - 1)
    sign = fmt["sign"]
    if sign == "sm":
        count = field & ((1 << fmt["mag_bits"]) - 1)
        if _bit(field, fmt["sign_bit"]):
            count = -count
    elif sign == "twos":
        count = field - (1 << width) if _bit(field, width - 1) else field
    else:
        count = -((~field) & ((1 << width) - 1)) if _bit(field, width - 1) else field
    if fmt["negate"]:
        count = -count
    if fmt["inch_bit"] >= 0 and _bit(frame, fmt["inch_bit"]):
        return _scale(count, fmt["inch_num"], fmt["inch_den"])
    return _scale(count, fmt["um_num"], fmt["um_den"])


def _nibble(frame, index):
    return (frame >> (4 * index)) & 0xF


def _decode_bcd7(fmt, frame):
    digits = 0
    for i in range(5, -1, -1):
        d = _nibble(frame, i)
        if d > 9:
            raise CaliperDecodeError("BCD digit %d is %d: glitch" % (i, d))
        digits = digits * 10 + d
    half = _bit(frame, fmt["half_bit"])
    if _bit(frame, fmt["metric_bit"]):
        if half:
            raise CaliperDecodeError("half flag set in metric mode: glitch")
        um = digits * 10  # 0.01 mm per digit
    else:
        # 0.001 in per digit, the half flag adds 0.0005 in: count in 0.0005 in units.
        um = _scale(digits * 2 + half, 127, 10)
    return -um if _bit(frame, fmt["neg_bit"]) else um


def _decode_digimatic(frame):
    for i in range(4):
        if _nibble(frame, i) != 0xF:
            raise CaliperDecodeError("digimatic header nibble %d is 0x%X, not 0xF" % (i, _nibble(frame, i)))
    sign = _nibble(frame, 4)
    if sign not in (0, 8):
        raise CaliperDecodeError("digimatic sign nibble %d; allowed 0 or 8" % sign)
    digits = 0
    for i in range(5, 11):
        d = _nibble(frame, i)
        if d > 9:
            raise CaliperDecodeError("digimatic digit %d is %d: glitch" % (i - 5, d))
        digits = digits * 10 + d
    point = _nibble(frame, 11)
    unit = _nibble(frame, 12)
    if point > 5 or unit > 1:
        raise CaliperDecodeError("digimatic point %d / unit %d out of range (0..5 / 0..1)" % (point, unit))
    den = 10 ** point
    um = _scale(digits, 25400 if unit else 1000, den)
    return -um if sign == 8 else um


def agree(readings_um, tolerance_um):
    """True when all readings lie within tolerance_um of each other."""
    return max(readings_um) - min(readings_um) <= tolerance_um


def mean_um(readings_um):
    """Mean of integer readings, rounded to the nearest um (halves away from zero).

    Display noise can put one frame a little more than half an LSB from the carriage;
    the mean of the agreeing frames is rarely that far off, and it is what CAL? reports.
    """
    n = len(readings_um)
    total = sum(readings_um)
    if total < 0:
        return -((-2 * total + n) // (2 * n))
    return (2 * total + n) // (2 * n)
