"""A folder holding several datasets (frame sources of different kinds) is refused, naming them,
instead of being read as one source because one subfolder qualifies."""

from __future__ import annotations

import pytest

from xcalib.errors import FormatError
from xcalib.io.sources import find_source, register_source, unregister_source


@pytest.fixture()
def two_kinds():
    # "alpha" accepts a folder holding an alpha.marker anywhere below (as a folder-of-scenes source does)
    register_source("test-alpha", lambda p: p.is_dir() and any(p.rglob("alpha.marker")), lambda p, **k: [],
                    priority=1)
    register_source("test-beta", lambda p: p.is_dir() and (p / "beta.marker").is_file(), lambda p, **k: [],
                    priority=2)
    yield
    unregister_source("test-alpha")
    unregister_source("test-beta")


def test_a_root_of_two_kinds_of_source_is_refused_naming_them(tmp_path, two_kinds):
    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes" / "alpha.marker").write_text("")
    (tmp_path / "recording").mkdir()
    (tmp_path / "recording" / "beta.marker").write_text("")
    with pytest.raises(FormatError) as e:
        find_source(tmp_path)
    msg = str(e.value)
    assert "2 kinds" in msg and "scenes (test-alpha)" in msg and "recording (test-beta)" in msg
    assert "give one of them" in msg
    assert find_source(tmp_path / "scenes").name == "test-alpha"  # each dataset alone is read


def test_a_folder_of_scenes_of_one_kind_is_still_read(tmp_path, two_kinds):
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "alpha.marker").write_text("")
    assert find_source(tmp_path).name == "test-alpha"
