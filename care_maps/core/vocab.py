"""Class vocabularies: the class names an encoder's text side embeds and queries ask for.

A vocabulary is an ordered list of unique class names. It comes from one of:

- a **bundled** vocabulary named by a bare word (``"scannet200"``); bundled files live in
  ``care_maps/data/vocabularies/`` and are only those whose licence allows redistribution (see the
  README there);
- a **taxonomy table** of the common 3D-scene datasets, recognised by its header row:

  ============================== ================= =====================================
  file (header starts with)      default column    other useful columns
  ============================== ================= =====================================
  Matterport category mapping    ``raw_category``  ``category``, ``mpcat40``, ``nyu40class``
  (``index  raw_category ...``)
  Matterport mpcat40             ``mpcat40``
  (``mpcat40index  mpcat40 ...``)
  ScanNet200 labels              ``name``
  (``index  scannet_id  name``)
  ScanNet v2 combined labels     ``raw_category``  ``category``, ``mpcat40``, ``nyu40class``
  (``id  raw_category ...``)
  ============================== ================= =====================================

  Any other tab-separated table works when its column is named with ``column=``;
- a **plain text** file, one class a line, ``#`` starting a comment, blank lines ignored.

Names are stripped and de-duplicated keeping the first occurrence, so row order (which in
these tables is frequency order) is kept: class ids downstream are positions in this list.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterable
from pathlib import Path

from care_maps.core.errors import EncoderError

__all__ = [
    "BUNDLED_DIR",
    "STRUCTURE_NAMES",
    "TAXONOMY_FORMATS",
    "bundled_vocabularies",
    "load_vocabulary",
    "mpcat40_of",
    "vocabulary_option",
]

BUNDLED_DIR = Path(__file__).resolve().parents[1] / "data" / "vocabularies"
"""Where the bundled vocabularies (``<name>.txt``) live: ``care_maps/data/vocabularies`` of the checkout."""

TAXONOMY_FORMATS: dict[tuple[str, ...], tuple[str, str]] = {
    ("index", "raw_category", "category"): ("Matterport category mapping", "raw_category"),
    ("mpcat40index", "mpcat40"): ("Matterport mpcat40", "mpcat40"),
    ("index", "scannet_id", "name"): ("ScanNet200 labels", "name"),
    ("id", "raw_category", "category"): ("ScanNet v2 combined labels", "raw_category"),
}
"""Leading header columns -> (format name, default column)."""


STRUCTURE_NAMES = frozenset({"void", "unlabeled", "wall", "floor", "ceiling"})
"""Lower-case names of a room's shell and of no label: not objects, so a simulated
perception never biases towards nor confuses with them, and a map's view names its
dominant object class without them."""


def bundled_vocabularies() -> list[str]:
    """Names of the vocabularies bundled with the project (``load_vocabulary(name)``)."""
    if not BUNDLED_DIR.is_dir():
        return []
    return sorted(p.stem for p in BUNDLED_DIR.glob("*.txt"))


def load_vocabulary(source: str | Path, *, column: str | None = None) -> list[str]:
    """Class names from a bundled vocabulary name or a file (format detected by its header).

    Args:
        source: a bundled vocabulary name (see :func:`bundled_vocabularies`) or a file path.
        column: for tab-separated tables, the column to read instead of the format's default
            (e.g. ``"mpcat40"`` or ``"category"`` of the Matterport category mapping).

    Raises:
        EncoderError: the file is missing or empty, its format is not recognised, or the
            column does not exist.
    """
    path = _resolve(source)
    text = _read_text(path)
    lines = text.splitlines()
    first = next((ln for ln in lines if ln.strip() and not ln.lstrip().startswith("#")), None)
    if first is None:
        msg = f"{path}: empty vocabulary; write one class name a line."
        raise EncoderError(msg)
    if "\t" in first:
        names = _table_column(path, text, column)
    else:
        if column is not None:
            msg = f"{path}: plain text vocabulary has no columns; drop column={column!r}."
            raise EncoderError(msg)
        names = [ln.split("#", 1)[0] for ln in lines]
    return _unique(names)


def mpcat40_of(
    names: Iterable[str], mapping: str | Path, *, default: str | None = None
) -> dict[str, str]:
    """The mpcat40 category of each raw category name, from a taxonomy table.

    ``mapping`` is a table with ``raw_category`` and ``mpcat40`` columns: Matterport's
    ``category_mapping.tsv`` or ScanNet's ``scannetv2-labels.combined.tsv``. Names match
    case-insensitively on ``raw_category``, then on ``category``.

    Args:
        names: raw category names to map.
        mapping: path of the table.
        default: category for names the table lacks; None raises instead.

    Raises:
        EncoderError: the table lacks the columns, or a name is unknown and no default given.
    """
    path = _resolve(mapping)
    rows = _table_rows(path, _read_text(path))
    header = rows[0]
    missing = [c for c in ("raw_category", "mpcat40") if c not in header]
    if missing:
        msg = f"{path}: no column {', '.join(missing)}; give Matterport's category_mapping.tsv or scannetv2-labels.combined.tsv."
        raise EncoderError(msg)
    lookup: dict[str, str] = {}
    for key_col in ("category", "raw_category"):  # raw_category last so it wins
        if key_col not in header:
            continue
        key_i, val_i = header.index(key_col), header.index("mpcat40")
        lookup.update(
            {r[key_i].strip().lower(): r[val_i].strip() for r in rows[1:] if len(r) > val_i}
        )
    result: dict[str, str] = {}
    unknown: list[str] = []
    for name in names:
        found = lookup.get(name.strip().lower(), default)
        if found is None:
            unknown.append(name)
        else:
            result[name] = found
    if unknown:
        shown = ", ".join(repr(n) for n in unknown[:5])
        more = f" and {len(unknown) - 5} more" if len(unknown) > 5 else ""
        msg = f"{path}: no mpcat40 category for {shown}{more}; pass default='misc' to map them anyway."
        raise EncoderError(msg)
    return result


def vocabulary_option(value: str) -> tuple[str, ...]:
    """What ``--vocabulary`` means in every command: a bundled vocabulary name, a vocabulary
    file, or comma-separated class names (``chair,sofa,lamp``; one bare name is one class)."""
    text = value.strip()
    if text in bundled_vocabularies() or ("," not in text and Path(text).is_file()):
        return tuple(load_vocabulary(text))
    names = tuple(dict.fromkeys(n.strip() for n in text.split(",") if n.strip()))
    if not names:
        msg = f"--vocabulary {value!r}: give a bundled name, a file, or comma-separated class names"
        raise EncoderError(msg)
    return names


def _resolve(source: str | Path) -> Path:
    """A bare word that names a bundled vocabulary means that file; anything else is a path."""
    if isinstance(source, str) and source in bundled_vocabularies():
        return BUNDLED_DIR / f"{source}.txt"
    path = Path(source)
    if not path.is_file():
        hint = ""
        if isinstance(source, str) and "/" not in source and not path.suffix:
            hint = f" Bundled vocabularies: {', '.join(bundled_vocabularies()) or 'none'}."
        msg = f"{path}: no such vocabulary file.{hint}"
        raise EncoderError(msg)
    return path


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as err:
        msg = f"{path}: not UTF-8 text ({err.reason}); give a text or .tsv vocabulary."
        raise EncoderError(msg) from err


def _table_rows(path: Path, text: str) -> list[list[str]]:
    rows = [r for r in csv.reader(io.StringIO(text), delimiter="\t") if any(c.strip() for c in r)]
    if not rows:
        msg = f"{path}: empty table."
        raise EncoderError(msg)
    rows[0] = [c.strip() for c in rows[0]]
    return rows


def _table_column(path: Path, text: str, column: str | None) -> list[str]:
    rows = _table_rows(path, text)
    header = rows[0]
    if column is None:
        fmt = next((v for k, v in TAXONOMY_FORMATS.items() if tuple(header[: len(k)]) == k), None)
        if fmt is None:
            msg = (
                f"{path}: unknown table format (columns {', '.join(header[:6])}...); "
                "pass column=NAME or give a plain text file, one class a line."
            )
            raise EncoderError(msg)
        column = fmt[1]
    if column not in header:
        msg = f"{path}: no column {column!r}; columns are {', '.join(header)}."
        raise EncoderError(msg)
    i = header.index(column)
    return [r[i] for r in rows[1:] if len(r) > i]


def _unique(names: Iterable[str]) -> list[str]:
    """Stripped, non-empty names, first occurrence kept (dict keeps insertion order)."""
    return list(dict.fromkeys(n.strip() for n in names if n.strip()))
