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


BAD = {
    "missing connect": ("", {}, "link.connect is not set"),
    "bad url": ('[link]\nconnect = "udpin:localhost"\n', {}, "SCHEME:HOST:PORT"),
    "unknown key": ('[link]\nconnect = "tcp:1.2.3.4:5"\nspeed = 3\n', {}, "unknown setting 'speed'"),
    "unknown section": ('[lnk]\nconnect = "x"\n', {}, "unknown setting"),
    "wrong type": ('[link]\nconnect = "tcp:1.2.3.4:5"\nsystem_id = "one"\n', {}, "link.system_id: expected an integer"),
    "range": ('[link]\nconnect = "tcp:1.2.3.4:5"\nsystem_id = 300\n', {}, "link.system_id must be in 1..255"),
    "inject mode": ('[link]\nconnect = "tcp:1.2.3.4:5"\n[inject]\nmode = "on"\n', {}, "mode must be one of"),
    "slow inject": ('[link]\nconnect = "tcp:1.2.3.4:5"\n[inject]\nmode = "inject"\nrate_hz = 2\n', {}, ">= 5"),
    "gps id": ('[link]\nconnect = "tcp:1.2.3.4:5"\n', {"inject.gps_id": 3}, "gps_id must be 0"),
    "stream": ('[link]\nconnect = "tcp:1.2.3.4:5"\n[streams]\nVFR_HUD = 4\n', {}, "unknown setting 'VFR_HUD'"),
    "no gps stream": ('[link]\nconnect = "tcp:1.2.3.4:5"\n[streams]\nGPS_RAW_INT = 0\n', {}, "GPS_RAW_INT must be"),
    "backoff": ('[link]\nconnect = "tcp:1.2.3.4:5"\nreconnect_min_s = 5.0\nreconnect_max_s = 1.0\n', {}, "reconnect_max_s"),
    "not toml": ("[link\nconnect=", {}, "not valid TOML"),
    "key file": ('[link]\nconnect = "tcp:1.2.3.4:5"\nsigning_key_file = "/nonexistent/key"\n', {}, "cannot read"),
    "nan": ('[link]\nconnect = "tcp:1.2.3.4:5"\nheartbeat_hz = nan\n', {}, "must be finite"),
}


@pytest.mark.parametrize("kind", BAD)
def test_bad_settings_are_clear_errors(kind, tmp_path):
    text, overrides, msg = BAD[kind]
    with pytest.raises(ConfigError, match=msg):
        load_config(write(tmp_path, text), overrides)


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
