"""Vocabularies read from the real taxonomy files in ../shared/data/labels/ and plain text."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from care_maps.core.errors import EncoderError
from care_maps.core.vocab import bundled_vocabularies, load_vocabulary, mpcat40_of


def _column(path: Path, name: str) -> list[str]:
    """Independent reference: the column read with the csv module, stripped, first kept."""
    with path.open(newline="", encoding="utf-8") as f:
        values = [r[name].strip() for r in csv.DictReader(f, delimiter="\t")]
    seen: list[str] = []
    for v in values:
        if v and v not in seen:
            seen.append(v)
    return seen


def test_matterport_category_mapping_raw_and_other_columns(shared_data: Path) -> None:
    path = shared_data / "labels" / "matterport_category_mapping.tsv"
    raw = load_vocabulary(path)
    assert len(raw) == 1659  # the file's distinct raw categories
    assert raw[:2] == ["wall", "door"]
    assert raw == _column(path, "raw_category")
    mpcat = load_vocabulary(path, column="mpcat40")
    assert mpcat == _column(path, "mpcat40")
    assert len(mpcat) == len(set(mpcat)) <= 42
    assert "\r" not in "".join(mpcat)  # the file has CRLF line ends
    assert load_vocabulary(path, column="category") == _column(path, "category")


def test_matterport_mpcat40(shared_data: Path) -> None:
    names = load_vocabulary(shared_data / "labels" / "matterport_mpcat40.tsv")
    assert len(names) == 42  # 0 void .. 41 unlabeled
    assert names[0] == "void"
    assert names[1] == "wall"
    assert names[-1] == "unlabeled"


def test_scannet200_file_and_bundled_copy_agree(shared_data: Path) -> None:
    from_file = load_vocabulary(shared_data / "labels" / "scannet200_labels.tsv")
    assert len(from_file) == 200
    assert from_file[:3] == ["wall", "chair", "floor"]
    assert from_file[-1] == "mattress"
    assert "scannet200" in bundled_vocabularies()
    assert load_vocabulary("scannet200") == from_file


def test_scannetv2_combined(shared_data: Path) -> None:
    path = shared_data / "labels" / "scannetv2-labels.combined.tsv"
    names = load_vocabulary(path)
    assert len(names) == 607
    assert names[:2] == ["wall", "chair"]
    assert load_vocabulary(path, column="nyu40class") == _column(path, "nyu40class")


def test_plain_text_comments_blank_lines_duplicates(tmp_path: Path) -> None:
    path = tmp_path / "classes.txt"
    path.write_text("# my classes\n  chair \n\ntable  # a comment\nchair\nsofa bed\n")
    assert load_vocabulary(path) == ["chair", "table", "sofa bed"]
    assert load_vocabulary(str(path)) == ["chair", "table", "sofa bed"]


def test_unknown_table_needs_a_column(tmp_path: Path) -> None:
    path = tmp_path / "mine.tsv"
    path.write_text("id\tlabel\n1\tlamp\n2\tbed\n")
    with pytest.raises(EncoderError, match=r"mine\.tsv: unknown table format .*column=NAME"):
        load_vocabulary(path)
    assert load_vocabulary(path, column="label") == ["lamp", "bed"]
    with pytest.raises(EncoderError, match=r"no column 'name'; columns are id, label"):
        load_vocabulary(path, column="name")


@pytest.mark.parametrize(
    ("content", "pattern"),
    [
        ("", r"empty vocabulary"),
        ("# only a comment\n\n", r"empty vocabulary"),
        (b"\xff\xfe\x00bad", r"not UTF-8 text"),
    ],
)
def test_bad_files(tmp_path: Path, content: str | bytes, pattern: str) -> None:
    path = tmp_path / "bad.txt"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    with pytest.raises(EncoderError, match=pattern):
        load_vocabulary(path)


def test_missing_file_and_unknown_name(tmp_path: Path) -> None:
    with pytest.raises(EncoderError, match=r"nothere\.txt: no such vocabulary file"):
        load_vocabulary(tmp_path / "nothere.txt")
    with pytest.raises(EncoderError, match=r"Bundled vocabularies: .*scannet200"):
        load_vocabulary("scannet2000")
    path = tmp_path / "a.txt"
    path.write_text("chair\n")
    with pytest.raises(EncoderError, match=r"plain text vocabulary has no columns"):
        load_vocabulary(path, column="name")


def test_mpcat40_of_matterport_and_scannet(shared_data: Path) -> None:
    mapping = shared_data / "labels" / "matterport_category_mapping.tsv"
    # Rows of the file, read by eye: 'wall' -> wall, 'door' -> door.
    with mapping.open(newline="") as f:
        rows = {r["raw_category"]: r["mpcat40"] for r in csv.DictReader(f, delimiter="\t")}
    some = ["wall", "door", *list(rows)[100:110]]
    got = mpcat40_of([*some, " WALL "], mapping)
    assert got == {**{n: rows[n] for n in some}, " WALL ": "wall"}
    scannet = shared_data / "labels" / "scannetv2-labels.combined.tsv"
    assert mpcat40_of(["chair", "kitchen cabinet"], scannet) == {
        "chair": "chair",
        "kitchen cabinet": "cabinet",
    }


def test_mpcat40_of_unknown_names(shared_data: Path) -> None:
    mapping = shared_data / "labels" / "matterport_category_mapping.tsv"
    with pytest.raises(EncoderError, match=r"no mpcat40 category for 'flux capacitor'"):
        mpcat40_of(["wall", "flux capacitor"], mapping)
    assert mpcat40_of(["flux capacitor"], mapping, default="misc") == {"flux capacitor": "misc"}
    with pytest.raises(EncoderError, match=r"no column raw_category, mpcat40"):
        mpcat40_of(["wall"], shared_data / "labels" / "scannet200_labels.tsv")
