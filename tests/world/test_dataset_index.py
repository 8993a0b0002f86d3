"""The one reader of a dataset's index.json, on hand-written indexes."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from care_maps.core.errors import WorldError
from care_maps.evaluate.pipeline import recordings_of
from care_maps.truth.dataset_index import IndexEntry, read_index


def test_every_listed_recording_counts_skipped_or_not(tmp_path: Path) -> None:
    """``skipped`` means "already up to date" when ``care sample make`` re-runs."""
    entries = [
        {"recording": "scene_000.mcap", "skipped": True},
        {"path": "b/scene_001.mcap", "name": "second", "store": "stores/s1"},
    ]
    (tmp_path / "index.json").write_text(json.dumps({"recordings": entries}))
    assert read_index(tmp_path) == [
        IndexEntry("scene_000", tmp_path / "scene_000.mcap"),
        IndexEntry("second", tmp_path / "b/scene_001.mcap", tmp_path / "stores/s1"),
    ]
    assert recordings_of(tmp_path) == [
        ("scene_000", tmp_path / "scene_000.mcap"),
        ("second", tmp_path / "b/scene_001.mcap"),
    ]


def test_a_bare_list_of_paths_is_an_index(tmp_path: Path) -> None:
    (tmp_path / "index.json").write_text(json.dumps(["x.bag"]))
    assert read_index(tmp_path) == [IndexEntry("x", tmp_path / "x.bag")]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("{not json", "not a readable dataset index"),
        ('{"recordings": []}', "lists no recordings"),
        ('[{"name": "a"}]', "names no recording"),
    ],
)
def test_bad_index_is_one_clear_error(tmp_path: Path, text: str, message: str) -> None:
    (tmp_path / "index.json").write_text(text)
    with pytest.raises(WorldError, match=message) as err:
        read_index(tmp_path)
    assert "\n" not in str(err.value)
