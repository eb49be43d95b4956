"""The Foxglove layout in the repository (docs/foxglove-layout.json, the classic layout JSON that Foxglove and
Lichtblick import from a file): its panels are the ones the README promises, and every topic and field it names is
one the companion records, with that schema."""

from __future__ import annotations

import json
import re

import pytest

import companion.inject.gps_input  # noqa: F401 - the recorded types, for their topics
import companion.nav.outputs  # noqa: F401
import companion.pipeline.denial  # noqa: F401
from companion.events import Event
from companion.pipeline.core import _MAP_TRACKS, AUTOPILOT_LOG_TOPIC, GNSS_MAP_TOPIC
from companion.record.schemas import dataclass_schema
from tests.conftest import REPO
from tests.helpers import subclasses

LAYOUT = REPO / "docs" / "foxglove-layout.json"
#: a message path: /topic, an optional {field=="value"} filter, then .field and an optional [index]
PATH = re.compile(r'(?P<topic>/[\w/]+)(\{(?P<key>\w+)=="(?P<value>\w+)"\})?\.(?P<field>\w+)(\[(?P<index>\d+)\])?')


def _leaves(node) -> list[str]:
    return [node] if isinstance(node, str) else _leaves(node["first"]) + _leaves(node["second"])


def _recorded_types() -> dict[str, type]:
    return {cls.topic: cls for cls in subclasses(Event) if cls.recorded and cls.topic != "/events"}


def test_layout_has_the_map_the_plots_and_the_log():
    layout = json.loads(LAYOUT.read_text())
    panels = layout["configById"]
    assert sorted(_leaves(layout["layout"])) == sorted(panels)  # every panel placed, none missing
    kinds = sorted(pid.split("!")[0] for pid in panels)
    assert kinds == ["Plot", "Plot", "RosOut", "map"]
    tracks = set(_MAP_TRACKS.values()) | {GNSS_MAP_TOPIC}
    (map_cfg,) = [c for pid, c in panels.items() if pid.startswith("map!")]
    assert set(map_cfg["topicColors"]) == tracks and map_cfg["followTopic"] in tracks
    assert set(map_cfg["disabledTopics"]) <= tracks and "/map/autopilot" not in map_cfg["disabledTopics"]
    (log_cfg,) = [c for pid, c in panels.items() if pid.startswith("RosOut!")]
    assert log_cfg["topicToRender"] == AUTOPILOT_LOG_TOPIC
    titles = {c.get("foxglovePanelTitle") for pid, c in panels.items() if pid.startswith("Plot!")}
    assert titles == {"Error (m)", "Horizontal accuracy (m)"}


def test_every_plotted_field_is_recorded():
    types = _recorded_types()
    paths = [p["value"] for pid, c in json.loads(LAYOUT.read_text())["configById"].items() if pid.startswith("Plot!")
             for p in c["paths"]]
    assert paths
    for path in paths:
        m = PATH.fullmatch(path)
        assert m, f"not a message path: {path}"
        props = dataclass_schema(types[m["topic"]])["properties"]
        field = props[m["field"]]
        if m["index"] is not None:
            assert field["type"] == "array", path
            field = field["items"]
        assert field["type"] == "number", path
        if m["key"]:
            assert props[m["key"]]["type"] == "string", path


@pytest.mark.parametrize("bad", ["/estimation/fused.sigma_h", "/estimation/nowhere.x", "/inject/gps_input.h_acc_m[0]"])
def test_the_field_check_can_fail(bad):
    types = _recorded_types()
    m = PATH.fullmatch(bad)
    with pytest.raises((KeyError, AssertionError)):
        props = dataclass_schema(types[m["topic"]])["properties"]
        field = props[m["field"]]
        if m["index"] is not None:
            assert field["type"] == "array"


def test_readme_names_the_layout():
    assert "docs/foxglove-layout.json" in (REPO / "README.md").read_text()
