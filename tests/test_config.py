"""TOML settings: defaults, overrides, and a clear error for every kind of bad setting."""

from __future__ import annotations

from pathlib import Path

import pytest

from companion.config import ConfigError, load_config, load_signing_key, parse_override

REPO = Path(__file__).resolve().parents[1]


def write(tmp_path, text: str) -> Path:
    p = tmp_path / "c.toml"
    p.write_text(text)
    return p


def test_example_file_loads():
    import tomllib

    example = REPO / "systemd" / "companion.toml"
    assert tomllib.loads(example.read_text())["link"]["connect"] == "/dev/ttyAMA0"
    # the example's serial device does not exist here: point it at a network link, all else as written
    cfg = load_config(example, {"link.connect": "tcp:127.0.0.1:5760"})
    assert cfg.link.baud == 921600 and cfg.inject.mode == "shadow" and cfg.inject.gps_id == 1
    assert cfg.record.out == "/var/lib/companion/" and cfg.streams.rates_hz["RAW_IMU"] == 50.0


def test_file_then_overrides(tmp_path):
    p = write(
        tmp_path,
        '[link]\nconnect = "tcp:127.0.0.1:5760"\nsystem_id = 1\n[inject]\nmode = "shadow"\ngps_id = 1\n'
        "[streams]\nRAW_IMU = 0\nSCALED_IMU2 = 25\nGPS_RAW_INT = 5\n",
    )
    cfg = load_config(p, {"inject.mode": "inject", "link.component_id": 192, "link.baud": None})
    assert cfg.link.connect == "tcp:127.0.0.1:5760" and cfg.link.component_id == 192
    assert cfg.inject.mode == "inject" and cfg.inject.gps_id == 1
    assert "RAW_IMU" not in cfg.streams.rates_hz and cfg.streams.rates_hz["SCALED_IMU2"] == 25.0
    assert cfg.streams.rates_hz["GPS_RAW_INT"] == 5.0
    flat = cfg.as_flat_dict()
    assert flat["inject.mode"] == "inject" and flat["link.connect"] == "tcp:127.0.0.1:5760"


def test_parse_override_reads_toml_values():
    assert parse_override("inject.rate_hz=8") == ("inject.rate_hz", 8)
    assert parse_override("link.allow_unsigned=true") == ("link.allow_unsigned", True)
    assert parse_override("link.connect=tcp:127.0.0.1:5760") == ("link.connect", "tcp:127.0.0.1:5760")
    with pytest.raises(ConfigError, match="section.key=value"):
        parse_override("nonsense")


C = '[link]\nconnect = "tcp:1.2.3.4:5"\n'
BAD = {
    "missing connect": ("", {}, "link.connect is not set"),
    "bad url": ('[link]\nconnect = "udpin:localhost"\n', {}, "SCHEME:HOST:PORT"),
    "unknown key": ('[link]\nconnect = "tcp:1.2.3.4:5"\nspeed = 3\n', {}, "unknown setting 'speed'"),
    "unknown section": ('[lnk]\nconnect = "x"\n', {}, "unknown setting"),
    "wrong type": ('[link]\nconnect = "tcp:1.2.3.4:5"\nsystem_id = "one"\n', {}, "link.system_id: expected an integer"),
    "range": ('[link]\nconnect = "tcp:1.2.3.4:5"\nsystem_id = 300\n', {}, "link.system_id: 300 is out of range 1..255"),
    "inject mode": ('[link]\nconnect = "tcp:1.2.3.4:5"\n[inject]\nmode = "on"\n', {}, "mode must be one of"),
    "slow inject": ('[link]\nconnect = "tcp:1.2.3.4:5"\n[inject]\nmode = "inject"\nrate_hz = 2\n', {}, ">= 5"),
    "gps id": ('[link]\nconnect = "tcp:1.2.3.4:5"\n', {"inject.gps_id": 3}, "inject.gps_id: 3 is out of range"),
    "stream": ('[link]\nconnect = "tcp:1.2.3.4:5"\n[streams]\nSCALED_PRESSURE = 4\n', {}, "unknown setting 'SCALED_PRESSURE'"),
    "no gps stream": ('[link]\nconnect = "tcp:1.2.3.4:5"\n[streams]\nGPS_RAW_INT = 0\n', {}, "GPS_RAW_INT must be"),
    "backoff": ('[link]\nconnect = "tcp:1.2.3.4:5"\nreconnect_min_s = 5.0\nreconnect_max_s = 1.0\n', {}, "reconnect_max_s"),
    "not toml": ("[link\nconnect=", {}, "not valid TOML"),
    "key file": ('[link]\nconnect = "tcp:1.2.3.4:5"\nsigning_key_file = "/nonexistent/key"\n', {}, "cannot read"),
    "flush forever": (C, {"record.flush_interval_s": 1e300}, "record.flush_interval_s: .* out of range"),
    "tiny stream rate": (C, {"streams.GPS_RAW_INT": 1e-40}, "streams.GPS_RAW_INT: rate .* out of range"),
    "runaway segments": (C, {"record.segment_s": 1e-9}, "record.segment_s must be 0"),
    "absurd gnss delay": (C, {"navigator.gnss_delay_s": 1e300}, "navigator.gnss_delay_s: .* out of range"),
    "huge timeout": (C, {"link.link_timeout_s": 1e9}, "link.link_timeout_s: .* out of range"),
    "nan": ('[link]\nconnect = "tcp:1.2.3.4:5"\nheartbeat_hz = nan\n', {}, "must be finite"),
    "serial baud": ('[link]\nconnect = "/dev/ttyACM0"\nbaud = 12345\n', {}, "baud rate 12345 is not supported"),
    "serial not a device": ('[link]\nconnect = "/dev/shm"\n', {}, "not a character device"),
}


@pytest.mark.parametrize("kind", BAD)
def test_bad_settings_are_clear_errors(kind, tmp_path):
    text, overrides, msg = BAD[kind]
    with pytest.raises(ConfigError, match=msg):
        load_config(write(tmp_path, text), overrides)


def test_a_serial_device_not_there_yet_is_a_setting_not_an_error():
    """A missing device is a link that is not up yet (the link manager retries it); its settings are still checked."""
    cfg = load_config(None, {"link.connect": "/dev/ttyCOMPANIONNOTTHERE", "link.baud": 921600})
    assert cfg.link.connect == "/dev/ttyCOMPANIONNOTTHERE" and cfg.link.baud == 921600


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.toml")


def test_signing_key_formats(tmp_path):
    raw = bytes(range(32))
    (tmp_path / "raw").write_bytes(raw)
    (tmp_path / "hex").write_text(raw.hex() + "\n")
    (tmp_path / "short").write_text("secret")
    assert load_signing_key(str(tmp_path / "raw")) == raw
    assert load_signing_key(str(tmp_path / "hex")) == raw
    with pytest.raises(ConfigError, match="32-byte key"):
        load_signing_key(str(tmp_path / "short"))


def test_cli_reports_config_errors_in_one_line(tmp_path):
    import subprocess
    import sys

    p = write(tmp_path, '[link]\nconnect = "tcp:127.0.0.1:5760"\n[inject]\nmode = "sometimes"\n')
    res = subprocess.run([sys.executable, "-m", "companion.cli", "run", "--config", str(p)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and res.stderr.startswith("companion: error:") and "mode must be one of" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1


def test_non_utf8_file_is_a_clear_error(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_bytes(b'[link]\nconnect = "tcp:1.2.3.4:5"\n# \xff\xfe\n')
    with pytest.raises(ConfigError, match="not UTF-8"):
        load_config(p)


def test_every_numeric_setting_has_a_range_holding_its_default():
    """No hole: every number of every section (and every scalar navigator setting) is range-checked at start."""
    import dataclasses

    from companion.config import _SECTIONS, StreamConfig, setting_range
    from companion.nav.config import NavigatorConfig

    tables = {**_SECTIONS, "streams": StreamConfig, "navigator": NavigatorConfig}
    checked = 0
    for name, cls in tables.items():
        d = cls()
        for f in dataclasses.fields(cls):
            v = getattr(d, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                continue
            rng = setting_range(f"{name}.{f.name}")
            assert rng is not None, f"{name}.{f.name} has no range"
            assert rng[0] <= v <= rng[1], f"{name}.{f.name} default {v} outside {rng}"
            checked += 1
    assert checked > 80


def test_the_sequential_gravity_filter_corrects_the_navigator_position_only(tmp_path):
    """Its fixes are a running filter's output: the navigator takes them as position only, unless told otherwise."""
    (tmp_path / "map.nc").write_bytes(b"")  # the settings check only that the file is there
    base = {"link.connect": "tcp:127.0.0.1:5760", "gravity.map": str(tmp_path / "map.nc")}
    assert not load_config(None, base).nav_config().position_fix_position_only  # the Viterbi default
    seq = {**base, "gravity.matcher": "sequential"}
    assert load_config(None, seq).nav_config().position_fix_position_only
    told = load_config(None, {**seq, "navigator.position_fix_position_only": False})
    assert not told.nav_config().position_fix_position_only


def test_the_gyro_heading_asks_for_its_gyro_message(tmp_path):
    """gravity.air_heading = "gyro" on HIGHRES_IMU requests that message at RAW_IMU's air-data rate; an unknown gyro
    source is refused."""
    (tmp_path / "map.nc").write_bytes(b"")
    base = {"link.connect": "tcp:127.0.0.1:5760", "gravity.map": str(tmp_path / "map.nc"),
            "gravity.matcher": "sequential", "gravity.reference": "air_data", "gravity.air_heading": "gyro"}
    assert "HIGHRES_IMU" not in load_config(None, base).streams.rates_hz  # RAW_IMU by default
    cfg = load_config(None, {**base, "gravity.air_gyro_source": "HIGHRES_IMU"})
    assert cfg.streams.rates_hz["HIGHRES_IMU"] == 25.0
    with pytest.raises(ConfigError, match="air_gyro_source"):
        load_config(None, {**base, "gravity.air_gyro_source": "SCALED_IMU9"})
