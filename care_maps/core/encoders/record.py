"""What a store remembers of the model that made it, and how later steps rebuild that model.

A store's features live in one model's space; every later step that embeds anything (a new
vocabulary, crops for instances, a free-text query) must use *that* model, not the encoder's
defaults. Ingest therefore records, in ``meta.json`` under ``encoder_record``, the encoder's
name, version and dimension and every option that shapes it: the weights directory (made
absolute) with a digest of its files, the precomputed features file and its text table, the
perception preset and seed. :func:`encoder_for_store` rebuilds the same model from that record
and checks it: a weights directory that moved or changed, another version or another
dimension is one clear error naming the option that fixes it (``--weights DIR``).

The record is a frozen dataclass (:class:`EncoderRecord`) so it can become part of a typed
store-metadata record as it is.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from care_maps.core.encoders.base import (
    DEFAULT_PERCEPTION,
    RECORDED_WHEN_SET,
    Encoder,
    EncoderOptions,
    Precision,
)
from care_maps.core.errors import EncoderError, StoreError
from care_maps.core.store import BATCH_SIZE, StoreMeta

__all__ = [
    "RECORD_KEY",
    "EncoderRecord",
    "encoder_for_store",
    "store_text_encoder",
    "text_encoder_for_store",
    "weights_digest",
]

RECORD_KEY = "encoder_record"
"""Key of the record in a store's ``meta.json``."""

_DIGEST_READ = ("config.json", "preprocessor_config.json", "tokenizer_config.json")
"""Small files of a ``save_pretrained`` directory hashed by content (the rest by name and size:
hashing gigabytes of weights at every fuse would cost more than the fuse)."""


def weights_digest(directory: Path) -> str:
    """sha256 over a weights directory: every file's relative name and size, and the bytes of
    its configuration files. Moving the directory keeps it; changing the model does not."""
    directory = Path(directory)
    h = hashlib.sha256()
    for path in sorted(p for p in directory.rglob("*") if p.is_file()):
        rel = path.relative_to(directory).as_posix()
        h.update(f"{rel}\0{path.stat().st_size}\n".encode())
        if path.name in _DIGEST_READ:
            h.update(path.read_bytes())
    return h.hexdigest()


@dataclass(frozen=True)
class EncoderRecord:
    """The encoder of a store and every option that shapes its embeddings."""

    name: str
    version: str
    dim: int
    weights: str | None = None
    """Absolute weights directory, or a checkpoint id (clip)."""
    weights_digest: str | None = None
    """:func:`weights_digest` of ``weights`` when it is a directory."""
    precomputed: str | None = None
    """Absolute path of the precomputed features file (precomputed)."""
    text_file: str | None = None
    """Absolute path of the precomputed encoder's class-name embeddings (``<stem>.text.parquet``)."""
    perception: str = DEFAULT_PERCEPTION
    seed: int = 0
    precision: Precision = Precision.FLOAT32
    """The image side's number format: crops for instance maps are encoded in it too."""

    @classmethod
    def of(cls, encoder: Encoder, options: EncoderOptions) -> EncoderRecord:
        """The record of an encoder built from ``options`` (at ingest)."""
        weights, digest = options.weights, None
        if weights is not None and Path(weights).expanduser().is_dir():
            local = Path(weights).expanduser().resolve()
            weights, digest = str(local), weights_digest(local)
        precomputed = text_file = None
        if options.precomputed is not None:
            from care_maps.core.encoders.precomputed import text_path_for

            precomputed = str(Path(options.precomputed).resolve())
            text_file = str(text_path_for(Path(precomputed)))
        return cls(
            name=encoder.name,
            version=encoder.version,
            dim=int(encoder.dim),
            weights=weights,
            weights_digest=digest,
            precomputed=precomputed,
            text_file=text_file,
            perception=options.perception,
            seed=int(options.seed),
            precision=Precision(options.precision),
        )

    def as_json(self) -> dict[str, Any]:
        """The record as ``meta.json`` keeps it: the options of
        :data:`care_maps.core.encoders.base.RECORDED_WHEN_SET` only where set, so a store
        made before they existed reads back as it was written."""
        record = asdict(self)
        default = EncoderRecord(self.name, self.version, self.dim)
        for name in RECORDED_WHEN_SET:
            if getattr(self, name) == getattr(default, name):
                record.pop(name)
            else:
                record[name] = str(record[name])
        return record

    @classmethod
    def from_json(cls, data: Any, where: Path) -> EncoderRecord:
        names = {f.name for f in fields(cls)}
        if not isinstance(data, dict) or not {"name", "version", "dim"} <= set(data):
            msg = f"{where}: the encoder record is malformed; re-run `care ingest --force`"
            raise EncoderError(msg)
        known = {k: v for k, v in data.items() if k in names}
        try:
            precision = Precision(known.get("precision", Precision.FLOAT32))
        except ValueError:
            msg = f"{where}: the encoder record's precision {known['precision']!r} is unknown; re-run `care ingest --force`"
            raise EncoderError(msg) from None
        return cls(**{**known, "precision": precision})

    def options(self, *, batch_size: int = BATCH_SIZE) -> EncoderOptions:
        return EncoderOptions(
            weights=self.weights,
            batch_size=batch_size,
            precomputed=Path(self.precomputed) if self.precomputed else None,
            perception=self.perception,
            seed=self.seed,
            precision=self.precision,
        )

    def with_weights(self, weights: Path | None) -> EncoderRecord:
        """The record with its weights directory moved to ``weights`` (``--weights``)."""
        if weights is None:
            return self
        return replace(self, weights=str(Path(weights).expanduser().resolve()))

    def check_weights(self) -> None:
        """The recorded weights directory exists and holds the model the store was made with."""
        if self.weights_digest is None or self.weights is None:
            return
        path = Path(self.weights)
        if not path.is_dir():
            msg = (
                f"the store was made with CLIP weights in {path}, which is gone; pass "
                "--weights DIR with the same model where it lives now"
            )
            raise EncoderError(msg)
        if weights_digest(path) != self.weights_digest:
            msg = (
                f"the CLIP weights in {path} are not the ones the store was made with (their "
                "files changed); pass --weights DIR with the original model, or re-ingest "
                "with `care ingest --force --weights DIR`"
            )
            raise EncoderError(msg)

    def check(self, encoder: Encoder) -> Encoder:
        """``encoder`` if it matches the record's dimension and version, else one clear error."""
        if int(encoder.dim) != self.dim:
            msg = (
                f"encoder {self.name!r} now gives {encoder.dim}-dimensional embeddings, the "
                f"store's features have {self.dim}; pass the weights it was made with (--weights)"
            )
            raise EncoderError(msg)
        same = encoder.version == self.version or (
            self.weights_digest is not None
            and _without_checkpoint(encoder.version) == _without_checkpoint(self.version)
        )
        if not same:
            msg = (
                f"the store was made with encoder {self.name!r} version {self.version!r}, this "
                f"program builds {encoder.version!r}; re-ingest with `care ingest --force`"
            )
            raise EncoderError(msg)
        return encoder


def _without_checkpoint(version: str) -> str:
    """A clip version without its directory name (a moved directory may be renamed)."""
    return version.split("+", 1)[-1]


def _record_of(meta: StoreMeta, where: Path) -> EncoderRecord:
    if meta.encoder_record is not None:
        return EncoderRecord.from_json(meta.encoder_record, where)
    enc = meta.encoder
    if enc is None:
        msg = f"{where}: the store has no encoder; re-run `care ingest` with --encoder"
        raise EncoderError(msg)
    # stores of the first release: the options are in the ingest config
    opts = meta.config.get("encoder_options") or {}
    return EncoderRecord(
        name=enc.name,
        version=enc.version,
        dim=enc.dim,
        weights=opts.get("weights"),
        precomputed=opts.get("precomputed"),
        perception=opts.get("perception", DEFAULT_PERCEPTION),
        seed=int(opts.get("seed", 0)),
    )


def _read_meta(store: Path) -> StoreMeta:
    """The store's typed metadata (:class:`care_maps.core.store.StoreMeta`), where the record lives."""
    try:
        return StoreMeta.read(Path(store))
    except StoreError as err:
        raise EncoderError(str(err)) from err


def store_record(store: Path, *, weights: Path | None = None) -> EncoderRecord:
    """The store's encoder record (``weights`` overrides a moved weights directory)."""
    return _record_of(_read_meta(store), Path(store) / "meta.json").with_weights(weights)


def encoder_for_store(
    store: Path, *, weights: Path | None = None, batch_size: int = BATCH_SIZE
) -> Encoder:
    """The encoder that made ``store``'s features, rebuilt from its record and checked."""
    from care_maps.core.encoders import make_encoder

    record = store_record(store, weights=weights)
    record.check_weights()
    return record.check(make_encoder(record.name, record.options(batch_size=batch_size)))


def text_encoder_for_store(store: Path, *, weights: Path | None) -> Encoder:
    """:func:`encoder_for_store` built by :meth:`Encoder.for_text`: the text side only
    (embedding class names or a query never needs the image side's weights)."""
    from care_maps.core.encoders import ENCODERS

    record = store_record(store, weights=weights)
    record.check_weights()
    return record.check(ENCODERS.load(record.name).for_text(record.options()))


def store_text_encoder(
    store: Path, *, weights: Path | None = None
) -> Callable[[Sequence[str]], np.ndarray] | None:
    """The store's own text side (texts -> (n, d) embeddings), or None when the model has no
    text side for arbitrary text (a precomputed store without a text table that knows it)."""
    record = store_record(store, weights=weights)
    if record.name == "precomputed":
        from care_maps.core.encoders.precomputed import lookup_text

        text_file = record.text_file
        if text_file is None or not Path(text_file).is_file():
            return None
        return lambda names: lookup_text(Path(text_file), names, record.dim)
    return text_encoder_for_store(store, weights=weights).encode_text
