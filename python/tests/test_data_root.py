"""The data root from Python: qdo.data_root() and qdo.dataset_path() as `qdo data` and --data see
them (include/qdo/data/data_root.hpp)."""
import os

import pytest

import qdo


def test_names_resolve_under_the_root_and_a_missing_one_says_where(tmp_path):
    (tmp_path / "cave").mkdir()
    assert qdo.dataset_path("cave", root=str(tmp_path)) == str(tmp_path / "cave")
    assert qdo.dataset_path("./cave", root=str(tmp_path)) == "./cave"  # a path is kept
    with pytest.raises(ValueError, match="kaist") as e:
        qdo.dataset_path("kaist", root=str(tmp_path))
    assert str(tmp_path / "kaist") in str(e.value)
    r = qdo.data_root(root=str(tmp_path))
    assert r["path"] == str(tmp_path) and r["exists"] and r["source"] == "--data-root"


def test_qdo_data_environment_variable(tmp_path, monkeypatch):
    (tmp_path / "icvl").mkdir()
    monkeypatch.setenv("QDO_DATA", str(tmp_path))
    assert qdo.data_root()["source"] == "QDO_DATA"
    assert qdo.dataset_path("icvl") == str(tmp_path / "icvl")
    monkeypatch.setenv("QDO_DATA", str(tmp_path / "absent"))
    with pytest.raises(ValueError, match="QDO_DATA"):
        qdo.data_root()


def test_a_root_that_is_no_folder_is_refused(tmp_path):
    with pytest.raises(ValueError, match="not a folder"):
        qdo.data_root(root=os.path.join(str(tmp_path), "nope"))
