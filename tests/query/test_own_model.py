"""A store remembers its model: a ``clip`` store made with ``--weights DIR`` fuses, recomputes
for new class names, builds crops and answers free text with that model and no download; a
moved or changed weights directory is one clear error. Checked against the same tiny CLIP
loaded directly (softmax and logsumexp from scipy)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from scipy.special import logsumexp, softmax

from care_maps.core.encoders import EncoderOptions, make_encoder
from care_maps.core.frames import Frame
from care_maps.ingest.write import write_recording
from care_maps.query.map import list_column

pytestmark = pytest.mark.slow

H, W = 48, 64
K = np.array([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])
OFFLINE = {**os.environ, "HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}


def _frames(n: int = 4) -> list[Frame]:
    """A grey floor with a red box (0.5 m tall), seen from 1.5 m above by sliding cameras."""
    out = []
    for i in range(n):
        depth = np.full((H, W), 1.5, np.float32)
        depth[10:30, 12:36] = 1.0
        rgb = np.full((H, W, 3), 128, np.uint8)
        rgb[10:30, 12:36] = (200, 30, 30)
        pose = np.eye(4)
        pose[:3, :3] = np.diag([1.0, -1.0, -1.0])  # optical frame looking straight down
        pose[:3, 3] = [0.05 * i, 0.0, 1.5]
        out.append(Frame(10**9 + i * 10**8, rgb, depth, K.copy(), pose))
    return out


def _care(*args: str, ok: bool = True) -> subprocess.CompletedProcess:
    done = subprocess.run(
        [sys.executable, "-m", "care_maps.cli.main", *map(str, args)],
        capture_output=True, text=True, env=OFFLINE,
    )  # fmt: skip
    if ok:
        assert done.returncode == 0, done.stderr[-2000:]
    return done


@pytest.fixture(scope="module")
def clip_store(tmp_path_factory: pytest.TempPathFactory, save_tiny_clip) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("own")
    weights = save_tiny_clip(root / "models" / "tiny-clip", layers=2)
    rec = write_recording(root / "rec.mcap", _frames(), fmt="mcap")
    store = root / "store"
    _care("ingest", rec, "--out", store, "--encoder", "clip", "--weights", weights,
          "--vocabulary", "chair,table,floor")  # fmt: skip
    return store, weights


def _direct(weights: Path):
    return make_encoder("clip", EncoderOptions(weights=str(weights)))


def test_store_records_its_model(clip_store) -> None:
    store, weights = clip_store
    record = json.loads((store / "meta.json").read_text())["encoder_record"]
    assert record["name"] == "clip"
    assert record["weights"] == str(weights.resolve())
    assert record["dim"] == 16
    assert record["weights_digest"]


def test_new_vocabulary_is_embedded_by_the_store_model(clip_store) -> None:
    store, weights = clip_store
    _care("fuse", "grid", store, "--cell-size", "0.1")
    _care("fuse", "grid", store, "--recompute", "--vocabulary", "lamp,sofa,chair")
    table = pq.read_table(store / "cells.parquet")
    md = table.schema.metadata
    assert json.loads(md[b"care.vocabulary"]) == ["lamp", "sofa", "chair"]
    text = _direct(weights).encode_text(["lamp", "sofa", "chair"])
    feats = list_column(table, "feature", np.float64)
    scale = float(md[b"care.logit_scale"])
    want = logsumexp(scale * feats @ text.T.astype(np.float64), axis=1)
    np.testing.assert_allclose(table.column("log_norm").to_numpy(), want, rtol=1e-4, atol=1e-3)


def test_crops_use_the_store_model(clip_store) -> None:
    store, _ = clip_store
    done = _care(
        "fuse", "instances", store, "--features", "crops", "--proposals", "geometric", ok=False
    )
    # a crops build either succeeds or says in one line why no proposal was found
    assert done.returncode == 0 or done.stderr.count("\n") == 1, done.stderr
    assert "huggingface" not in done.stderr.lower()


def test_free_text_joins_the_vocabulary_through_clip(clip_store) -> None:
    store, weights = clip_store
    _care("fuse", "grid", store, "--cell-size", "0.1")
    done = _care("query", store, "a red chair", "--map", "grid", "--top", "3", "--json")
    out = json.loads(done.stdout)
    assert out["method"].startswith("joins the vocabulary [clip")
    table = pq.read_table(store / "cells.parquet")
    vocab = json.loads(table.schema.metadata[b"care.vocabulary"])
    scale = float(table.schema.metadata[b"care.logit_scale"])
    text = _direct(weights).encode_text([*vocab, "a red chair"]).astype(np.float64)
    feats = list_column(table, "feature", np.float64)
    probs = softmax(scale * feats @ text.T, axis=1)[:, -1]
    top = out["candidates"][0]
    assert top["confidence"] == pytest.approx(probs.max(), rel=1e-3)
    assert top["confidence"] == pytest.approx(probs[top["candidate"]], rel=1e-3)


_IMPORTS_AFTER_QUERY = """
import sys
from care_maps.cli.main import main
sys.argv = ["care", "query", *sys.argv[1:]]
try:
    main()
except SystemExit as exit_:
    assert not exit_.code, exit_.code
print(sorted(m for m in ("torch", "transformers") if m in sys.modules), file=sys.stderr)
"""


def test_a_class_name_query_loads_no_model(clip_store) -> None:
    """A class of the vocabulary is answered from the store's own text embeddings: a cold
    query never imports torch or transformers (their import alone takes seconds)."""
    store, _ = clip_store
    _care("fuse", "grid", store, "--cell-size", "0.1")
    # the map's vocabulary is the store's cached one (another test recomputes it)
    _care("fuse", "grid", store, "--recompute", "--vocabulary", "chair,table,floor")
    done = subprocess.run(
        [sys.executable, "-c", _IMPORTS_AFTER_QUERY, str(store), "chair", "--map", "grid"],
        capture_output=True, text=True, env=OFFLINE, check=True,
    )  # fmt: skip
    assert done.stderr.strip().splitlines()[-1] == "[]"


def test_free_text_loads_the_text_tower_alone(clip_store) -> None:
    """Free text needs only CLIP's text tower; its embeddings are the whole model's."""
    from transformers import CLIPTextModelWithProjection

    from care_maps.core.encoders.record import store_text_encoder

    store, weights = clip_store
    embed = store_text_encoder(store)
    assert type(embed.__self__.model) is CLIPTextModelWithProjection
    texts = ["a red chair", "somewhere to sit"]
    np.testing.assert_allclose(
        embed(texts), _direct(weights).encode_text(texts), rtol=1e-5, atol=1e-6
    )


def test_moved_or_changed_weights_are_one_clear_error(clip_store, tmp_path: Path) -> None:
    store, weights = clip_store
    _care("fuse", "grid", store, "--cell-size", "0.1")
    moved = tmp_path / "elsewhere"
    shutil.copytree(weights, moved)
    hidden = weights.with_name("tiny-clip.hidden")
    weights.rename(hidden)
    try:
        gone = _care("query", store, "a red chair", "--map", "grid", "--json", ok=False)
        assert gone.returncode == 1
        assert gone.stderr.count("\n") == 1
        assert "--weights" in gone.stderr
        assert "Traceback" not in gone.stderr
        found = _care("query", store, "a red chair", "--map", "grid", "--json", "--weights", moved)
        assert json.loads(found.stdout)["method"].startswith("joins the vocabulary [clip")
        config = moved / "config.json"
        config.write_text(
            config.read_text().replace('"projection_dim": 16', '"projection_dim": 16 ')
        )
        changed = _care("query", store, "lamp", "--map", "grid", "--weights", moved, ok=False)
        assert changed.returncode == 1
        assert "not the ones the store was made with" in changed.stderr
    finally:
        hidden.rename(weights)
