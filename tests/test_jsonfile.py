"""Every JSON a user hands over fails with the file's name and the reader's own error type."""

import pytest

from kitchenbot.calibration.files import CalibrationFileError, load_corners
from kitchenbot.jsonfile import read_json
from kitchenbot.world.inventory import Inventory, InventoryError


class BadFile(ValueError):
    pass


def test_read_json_names_the_file(tmp_path):
    good = tmp_path / "good.json"
    good.write_text('{"a": [1, 2]}')
    assert read_json(good, BadFile, "a test file") == {"a": [1, 2]}
    broken = tmp_path / "broken.json"
    broken.write_text('{"a": ')
    with pytest.raises(BadFile, match=r"broken\.json: not valid JSON \(a test file"):
        read_json(broken, BadFile, "a test file")
    with pytest.raises(BadFile, match=r"missing\.json: cannot read a test file"):
        read_json(tmp_path / "missing.json", BadFile, "a test file")


def test_corner_file_and_models_info_errors_name_the_file(tmp_path):
    samples = tmp_path / "samples.json"
    samples.write_text("not json")
    with pytest.raises(CalibrationFileError, match=r"samples\.json: not valid JSON"):
        load_corners(samples)
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "models_info.json").write_text("{")
    with pytest.raises(InventoryError, match=r"models_info\.json: not valid JSON"):
        Inventory.load(tmp_path / "models")
