"""``invent up --mapping`` (issue 52): refused, exit 2 naming why before anything starts, where it
cannot build a map: outside goal mode, or with a map given; ``navigation.mapping`` with
``navigation.map`` likewise."""

from __future__ import annotations

import pytest

from services.config import ConfigError, load_config
from tests.harness import refused


def test_mapping_needs_goal_mode(capsys: pytest.CaptureFixture[str]) -> None:
    code, _out, err = refused(capsys, "up", "--mapping")
    assert code == 2 and "--mapping" in err and "--goals" in err


def test_mapping_takes_no_map(capsys: pytest.CaptureFixture[str], tmp_path) -> None:
    code, _out, err = refused(capsys, "up", "--goals", "--mapping", "--map", str(tmp_path / "map.yaml"))
    assert code == 2 and "--mapping with --map" in err


def test_the_setting_takes_no_map_either() -> None:
    with pytest.raises(ConfigError, match="mapping"):
        load_config(None, {"navigation.mapping": True, "navigation.map": "floor.yaml"})
