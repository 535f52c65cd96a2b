# Board configuration: defaults, JSON loading and checks. Pure logic.
import json

import caliper_decode

CONFIG_FILE = "stage.json"

DEFAULTS = {
    "serial": "",               # empty: machine.unique_id() in hex
    "pins": {"step": 14, "dir": 12, "enable": 13, "lim_min": 4, "lim_max": 5,
             "cal_clk": 0, "cal_data": 2, "cal_zero": 15, "cal_power": 16},
    "enable_active": 0,         # TB6560 EN input level that enables the driver
    "dir_positive": 1,          # DIR level for increasing steps
    "limit_active": 0,          # switch level when pressed (to GND with pull-up)
    "step_pulse_us": 40,        # TB6560 needs > 30 us with 330 pF on Cosc
    "dir_setup_us": 50,
    "start_hz": 400,
    "max_hz": 1600,
    "max_hz_cap": 4000,         # SPEED can not exceed this
    "accel_hz_per_s": 8000,
    "home_hz": 600,
    "home_backoff_steps": 60,
    "travel_steps": 13500,      # machine soft limits are 0..travel_steps after HOME
    "home_required": True,
    "caliper": {"format": "bin6", "settings": {}, "clk_idle": 1, "sample": "leave",
                "data_invert": 0, "gap_us": 5000, "timeout_ms": 400, "confirm": 2,
                "agree_um": 10, "poll_ms": 1000, "zero_pulse_ms": 100,
                "host_half_us": 55},
    "uart": {"id": 0, "baud": 115200, "detach_repl": True},
    "tcp": {"enable": True, "port": 23},
    "wifi": {"mode": "sta", "ssid": "", "password": "", "ap_ssid": "elphel-stage"},
    "watchdog": True,
}

LIMITS = {
    "step_pulse_us": (2, 1000), "dir_setup_us": (1, 10000), "start_hz": (10, 20000),
    "max_hz": (10, 20000), "max_hz_cap": (10, 20000), "accel_hz_per_s": (1, 1000000),
    "home_hz": (10, 20000), "home_backoff_steps": (1, 100000), "travel_steps": (1, 10000000),
}


class ConfigError(ValueError):
    pass


def merge(base, over, where=""):
    out = dict(base)
    for key in over:
        if key not in base:
            raise ConfigError("config key %s%s unknown; allowed: %s"
                              % (where, key, ", ".join(sorted(base))))
        if isinstance(base[key], dict) and key != "settings":
            if not isinstance(over[key], dict):
                raise ConfigError("config %s%s must be an object" % (where, key))
            out[key] = merge(base[key], over[key], where + key + ".")
        else:
            out[key] = over[key]
    return out


def check(cfg):
    for key in LIMITS:
        lo, hi = LIMITS[key]
        v = cfg[key]
        if not isinstance(v, int) or not lo <= v <= hi:
            raise ConfigError("config %s=%r; allowed integer %d..%d" % (key, v, lo, hi))
    if not cfg["start_hz"] <= cfg["max_hz"] <= cfg["max_hz_cap"]:
        raise ConfigError("config needs start_hz <= max_hz <= max_hz_cap, got %d, %d, %d"
                          % (cfg["start_hz"], cfg["max_hz"], cfg["max_hz_cap"]))
    cal = cfg["caliper"]
    cfg["caliper_format"] = caliper_decode.make_format(cal["format"], cal["settings"])
    if cal["sample"] not in ("leave", "return"):
        raise ConfigError("config caliper.sample=%r; allowed leave, return" % (cal["sample"],))
    if cal["confirm"] < 1:
        raise ConfigError("config caliper.confirm=%r; allowed >= 1" % (cal["confirm"],))
    return cfg


def parse(text):
    try:
        data = json.loads(text)
    except ValueError as e:
        raise ConfigError("config is not valid JSON: %s" % e)
    if not isinstance(data, dict):
        raise ConfigError("config must be a JSON object")
    return check(merge(DEFAULTS, data))


def load(path=CONFIG_FILE):
    try:
        f = open(path)
    except OSError:
        return check(merge(DEFAULTS, {}))
    try:
        return parse(f.read())
    finally:
        f.close()
