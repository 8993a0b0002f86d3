"""CLIP through Hugging Face ``transformers``: dense per-view maps the MaskCLIP way, crops, text.

Dense features (why this way). CLIP's vision transformer is trained to align only its
class token with text; its final patch tokens, after the last self-attention has mixed
every patch with the global context, carry little local meaning. MaskCLIP (Zhou et al.,
"Extract Free Dense Labels from CLIP", ECCV 2022) observed that the *value* embeddings of
the last attention layer are local and already live where the class token's pre-projection
features live: for each patch token ``x`` entering the last layer it takes

    out_proj(v_proj(layer_norm1(x)))

skipping the query-key attention, the residual and the MLP of that layer (adding either
back degrades the segmentation), and sends it through the same ``post_layernorm`` and
``visual_projection`` as the class token, which puts it in the text embedding space. We
do exactly that, with no extra weights, so any CLIP ViT checkpoint works. The result is
one ``d``-vector per patch: a (fh, fw, d) map at the patch stride.

Resolution. The whole image is resized (not cropped, so that feature cell (i, j) covers
the image rows ``i*H/fh ..`` and columns ``j*W/fw ..`` as the store's pixel-to-cell rule
says) to a patch-aligned size whose short side is ``short_side`` pixels (default: twice the
checkpoint's training size, 448 for the ViT-B models, giving 14 x 19 cells for a 640 x 480
view with patch 32), and the position embeddings are interpolated to that grid, as
MaskCLIP does for its higher-resolution inference. Pixel scaling and normalisation follow
the checkpoint's ``CLIPImageProcessor``. Crops go through the processor unchanged (resize
the short side, centre-crop), which is what CLIP saw in training.

Text. Class names become prompts ``"a photo of a {}."`` (underscores read as spaces, as in
``tv_monitor``) embedded by ``get_text_features``.

Note: in transformers 5 ``get_image_features`` / ``get_text_features`` return a model
output whose ``pooler_output`` holds the projected embedding; transformers 4 returned the
tensor itself. :func:`_pooled` accepts both.
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple, cast

import numpy as np

from care_maps.core.encoders.base import Encoder, EncoderOptions, Precision
from care_maps.core.errors import EncoderError
from care_maps.core.frames import Frame

if TYPE_CHECKING:
    from transformers import CLIPTextConfig

__all__ = ["DEFAULT_CHECKPOINT", "PROMPT_TEMPLATE", "ClipEncoder", "PreparedBatch"]

DEFAULT_CHECKPOINT = "openai/clip-vit-base-patch32"
"""Used when no ``--weights`` is given; needs a download (or the Hugging Face cache)."""

PROMPT_TEMPLATE = "a photo of a {}."
"""CLIP's standard zero-shot prompt; the class name replaces ``{}``."""


class PreparedBatch(NamedTuple):
    """Views made ready for the vision tower (:meth:`ClipEncoder.prepare_views`)."""

    pixels: Any
    """(B, 3, fh * patch, fw * patch) float32 tensor, resized and normalised."""
    fh: int
    fw: int


class ClipEncoder(Encoder):
    """Dense MaskCLIP features, crop features and text embeddings from one CLIP checkpoint.

    Reads ``options.weights`` (a directory written by ``save_pretrained`` holding the model,
    tokenizer and image processor, or a checkpoint id where downloads are possible),
    ``options.device`` and ``options.batch_size``.
    """

    name = "clip"
    supports_crops = True
    precisions = frozenset({Precision.FLOAT32, Precision.BFLOAT16})

    def __init__(
        self,
        options: EncoderOptions,
        *,
        short_side: int | None = None,
        prompt: str = PROMPT_TEMPLATE,
    ) -> None:
        import torch

        self._setup(options, prompt)
        self.precision = Precision(options.precision)
        if self.precision is Precision.BFLOAT16:
            _check_bfloat16(self.device)
        self.model, self.tokenizer, self.processor = _load(self.weights)
        self.model.to(self.device).eval()
        vision = self.model.config.vision_config
        self.patch = int(vision.patch_size)
        self.short_side = int(short_side or 2 * vision.image_size)
        if self.short_side < self.patch:
            msg = f"short_side {self.short_side} is below the patch size {self.patch}"
            raise EncoderError(msg)
        self.max_tokens = int(self.model.config.text_config.max_position_embeddings)
        self.dim = int(self.model.config.projection_dim)
        scale = float(getattr(self.processor, "rescale_factor", 1 / 255))
        mean = torch.tensor(self.processor.image_mean, dtype=torch.float32)
        std = torch.tensor(self.processor.image_std, dtype=torch.float32)
        # uint8 -> normalised input in one multiply-add: (x * scale - mean) / std
        self._gain = (scale / std).view(1, 3, 1, 1).to(self.device)
        self._bias = (-mean / std).view(1, 3, 1, 1).to(self.device)

    def _setup(self, options: EncoderOptions, prompt: str) -> None:
        """What both the whole encoder and its text side take from the options."""
        import torch
        import transformers

        self.weights = options.weights or DEFAULT_CHECKPOINT
        self.batch_size = max(1, int(options.batch_size))
        self.device = torch.device(
            options.device or ("cuda" if torch.cuda.is_available() else "cpu")
        )
        self.prompt = prompt
        checkpoint = Path(self.weights).name if Path(self.weights).is_dir() else self.weights
        self.version = f"{checkpoint}+transformers-{transformers.__version__}+maskclip"

    @classmethod
    def for_text(cls, options: EncoderOptions) -> ClipEncoder:
        """The text tower and tokenizer alone (``CLIPTextModelWithProjection``): a free-text
        query embeds one prompt and never runs the image side, whose weights are most of a
        ViT checkpoint's memory. :meth:`encode_text` gives the whole model's embeddings."""
        self = cls.__new__(cls)
        self._setup(options, PROMPT_TEMPLATE)
        self.model, self.tokenizer = _load_text(self.weights)
        self.model.to(self.device).eval()
        self.processor = None
        self.precision = Precision.FLOAT32  # the text side is full precision at every setting
        self.max_tokens = int(self.model.config.max_position_embeddings)
        self.dim = int(self.model.config.projection_dim)
        return self

    # -- image side -------------------------------------------------------------------------

    def grid_shape(self, height: int, width: int) -> tuple[int, int]:
        """(fh, fw) of the dense map of an ``height`` x ``width`` view."""
        scale = self.short_side / min(height, width)
        fh = max(1, round(height * scale / self.patch))
        fw = max(1, round(width * scale / self.patch))
        return fh, fw

    def encode_views(self, frames: Sequence[Frame]) -> np.ndarray:
        """Dense (B, fh, fw, d) float32 maps, L2-normalised per cell; views share one size."""
        return self.encode_prepared(self.prepare_views(frames))

    def prepare_views(self, frames: Sequence[Frame]) -> list[PreparedBatch]:
        """The model's inputs for ``frames``, one :class:`PreparedBatch` per ``batch_size``
        views: resized to the patch grid and normalised, on the encoder's device. All of
        :meth:`encode_views` but the forward pass, so ingest runs it on a background thread
        for the next batch while this one is in the model."""
        if not frames:
            return []
        sizes = {(f.height, f.width) for f in frames}
        if len(sizes) > 1:
            msg = f"views of different sizes {sorted(sizes)} in one batch; encode them separately"
            raise EncoderError(msg)
        height, width = sizes.pop()
        fh, fw = self.grid_shape(height, width)
        return [
            PreparedBatch(
                self.pixels(np.stack([f.rgb for f in frames[i : i + self.batch_size]]), fh, fw),
                fh,
                fw,
            )
            for i in range(0, len(frames), self.batch_size)
        ]

    def encode_prepared(self, prepared: Sequence[PreparedBatch]) -> np.ndarray:
        """Dense maps of what :meth:`prepare_views` made: the forward pass alone."""
        if not prepared:
            return np.zeros((0, 0, 0, self.dim), np.float32)
        return np.concatenate([self.dense(batch.pixels, batch.fh, batch.fw) for batch in prepared])

    def pixels(self, rgb: np.ndarray, fh: int, fw: int) -> Any:
        """(B, 3, fh * patch, fw * patch) float32 model input of (B, H, W, 3) uint8 views:
        resized whole (bicubic, antialiased, clipped to the uint8 range) and normalised as
        the checkpoint's image processor does."""
        import torch
        import torch.nn.functional as F

        with torch.no_grad():
            x = torch.from_numpy(rgb).to(self.device).permute(0, 3, 1, 2).float()
            size = (fh * self.patch, fw * self.patch)
            if tuple(x.shape[2:]) != size:
                x = F.interpolate(x, size=size, mode="bicubic", antialias=True, align_corners=False)
                x = x.clamp(0.0, 255.0)  # bicubic overshoots; the uint8 pipeline would clip
            return x * self._gain + self._bias

    def dense(self, pixels: Any, fh: int, fw: int) -> np.ndarray:
        """The forward pass: (B, fh, fw, d) float32 MaskCLIP maps of :meth:`pixels`' input."""
        import torch
        import torch.nn.functional as F

        vision = self.model.vision_model
        with torch.no_grad():
            with self._image_precision():
                hidden = vision.embeddings(pixels, interpolate_pos_encoding=True)
                hidden = vision.pre_layrnorm(hidden)
                *layers, last = vision.encoder.layers
                for layer in layers:
                    hidden = layer(hidden, None)
                attn = last.self_attn
                values = attn.out_proj(attn.v_proj(last.layer_norm1(hidden[:, 1:])))
                feats = self.model.visual_projection(vision.post_layernorm(values))
            feats = F.normalize(feats.float(), dim=-1)
        return feats.reshape(len(pixels), fh, fw, self.dim).float().cpu().numpy()

    def encode_crops(self, crops: Sequence[np.ndarray]) -> np.ndarray:
        """Whole-crop features (B, d) of (h, w, 3) uint8 crops, L2-normalised."""
        import torch
        import torch.nn.functional as F

        out = [np.zeros((0, self.dim), np.float32)]
        for i in range(0, len(crops), self.batch_size):
            batch = [np.asarray(c, dtype=np.uint8) for c in crops[i : i + self.batch_size]]
            if any(c.ndim != 3 or c.shape[2] != 3 or 0 in c.shape for c in batch):
                shapes = [c.shape for c in batch]
                msg = f"crops must be non-empty (h, w, 3) uint8 arrays, got shapes {shapes}"
                raise EncoderError(msg)
            pixels = self.processor(images=batch, return_tensors="pt")["pixel_values"]
            with torch.no_grad():
                with self._image_precision():
                    emb = _pooled(
                        self.model.get_image_features(pixel_values=pixels.to(self.device))
                    )
                out.append(F.normalize(emb.float(), dim=-1).cpu().numpy())
        return np.concatenate(out)

    def _image_precision(self) -> AbstractContextManager[Any]:
        """The context the vision tower runs in: bfloat16 autocast (its matrix products in
        bfloat16, weights kept float32) for :attr:`Precision.BFLOAT16`, else none at all."""
        if self.precision is Precision.FLOAT32:
            return nullcontext()
        import torch

        return torch.autocast(device_type=self.device.type, dtype=torch.bfloat16)

    # -- text side --------------------------------------------------------------------------

    def encode_text(self, names: Sequence[str]) -> np.ndarray:
        """(n, d) float32 L2-normalised embeddings of the prompted class names.

        A vocabulary longer than one batch is embedded in batches of prompts of similar
        token length, each padded to its longest prompt: the text tower's cost is its padded
        tokens (ScanNet200's 200 prompts on ViT-B/32, one thread, a tokenizer of one token a
        letter: 4.3 s instead of 5.8). A vocabulary of one batch is embedded as given, in one
        call. Threads are the caller's: ingest runs it on the forward pass's."""
        prompts = [self.prompt.format(n.replace("_", " ").strip()) for n in names]
        size = max(self.batch_size, 64)
        order = np.arange(len(prompts))
        if len(prompts) > size:
            lengths = [len(ids) for ids in self.tokenizer(prompts, truncation=True,
                       max_length=self.max_tokens)["input_ids"]]  # fmt: skip
            order = np.argsort(lengths, kind="stable")
        out = np.zeros((len(prompts), self.dim), np.float32)
        for i in range(0, len(prompts), size):
            rows = order[i : i + size]
            out[rows] = self._text_batch([prompts[j] for j in rows])
        return out

    def _text_batch(self, prompts: list[str]) -> np.ndarray:
        """(n, d) unit embeddings of one batch of prompts, padded to its longest."""
        import torch
        import torch.nn.functional as F

        tokens = self.tokenizer(
            prompts,
            padding=True,
            truncation=True,
            max_length=self.max_tokens,
            return_tensors="pt",
        )
        inputs = {
            "input_ids": tokens["input_ids"].to(self.device),
            "attention_mask": tokens["attention_mask"].to(self.device),
        }
        with torch.no_grad():
            if self.processor is None:  # the text tower alone (for_text)
                emb = self.model(**inputs).text_embeds
            else:
                emb = _pooled(self.model.get_text_features(**inputs))
            return F.normalize(emb, dim=-1).float().cpu().numpy()


def _check_bfloat16(device: Any) -> None:
    """Refuse bfloat16 where the device computes it only by emulation (slower than float32,
    which defeats its purpose): a CPU without AVX-512 (oneDNN's test), a GPU without it."""
    import torch

    if device.type == "cuda":
        supported = bool(torch.cuda.is_bf16_supported())
    elif device.type == "cpu":
        supported = bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    else:
        supported = True  # another backend: autocast refuses for itself
    if not supported:
        msg = (
            f"--precision bfloat16: this {device.type.upper()} has no bfloat16 arithmetic; "
            "use --precision float32"
        )
        raise EncoderError(msg)


def _pooled(output: Any) -> Any:
    """The projected embedding whether transformers returned a tensor (4.x) or an output (5.x)."""
    pooled = getattr(output, "pooler_output", None)
    return output if pooled is None else pooled


def _source(weights: str) -> tuple[str, bool]:
    """Where ``from_pretrained`` reads (a directory or a checkpoint id) and whether it is a
    local directory; a path that names no directory is one clear error."""
    path = Path(weights).expanduser()
    looks_local = path.is_absolute() or weights.startswith((".", "~")) or path.exists()
    if looks_local and not path.is_dir():
        msg = f"--weights {weights}: no such directory; give a folder written by CLIPModel.save_pretrained."
        raise EncoderError(msg)
    return (str(path) if looks_local else weights), looks_local


def _load_text(weights: str) -> tuple[Any, Any]:
    """The text tower with its projection and the tokenizer, from a whole CLIP checkpoint.

    The checkpoint's image weights are left unread; transformers reports them as unexpected
    keys, which is the point, so its loading report is silenced for this call."""
    import torch
    from transformers import AutoTokenizer, CLIPConfig, CLIPTextModelWithProjection
    from transformers.utils import logging as hf_logging

    source, looks_local = _source(weights)
    level = hf_logging.get_verbosity()
    hf_logging.set_verbosity_error()
    try:
        # the text config of a whole checkpoint may keep its own default projection size;
        # the whole model's projection_dim is what the text projection was saved with
        whole = CLIPConfig.from_pretrained(source)
        text = cast("CLIPTextConfig", whole.text_config)  # a config object once loaded
        text.projection_dim = whole.projection_dim
        model = CLIPTextModelWithProjection.from_pretrained(
            source, config=text, dtype=torch.float32
        )
        tokenizer = AutoTokenizer.from_pretrained(source)
    except (OSError, ValueError, KeyError) as err:
        raise _load_error(err, weights, source, looks_local) from err
    finally:
        hf_logging.set_verbosity(level)
    return model, tokenizer


def _load(weights: str) -> tuple[Any, Any, Any]:
    """Model, tokenizer and image processor from a directory or checkpoint id, or one clear error."""
    import torch
    from transformers import AutoImageProcessor, AutoTokenizer, CLIPModel

    source, looks_local = _source(weights)
    try:
        model = CLIPModel.from_pretrained(source, dtype=torch.float32)
        tokenizer = AutoTokenizer.from_pretrained(source)
        processor = AutoImageProcessor.from_pretrained(source)
    except (OSError, ValueError, KeyError) as err:
        raise _load_error(err, weights, source, looks_local) from err
    if getattr(model.config.vision_config, "patch_size", None) is None:
        msg = f"{source}: not a CLIP ViT checkpoint (no patch size); dense features need a ViT."
        raise EncoderError(msg)
    return model, tokenizer, processor


def _load_error(err: Exception, weights: str, source: str, looks_local: bool) -> EncoderError:
    """The one line for a checkpoint that cannot be loaded, naming where it was looked for."""
    text = str(err).strip()
    reason = text.splitlines()[0].rstrip(".") if text else type(err).__name__
    where = (
        f"directory {source}"
        if looks_local
        else f"checkpoint {weights!r} (neither downloadable from here nor in the Hugging Face cache)"
    )
    msg = (
        f"cannot load CLIP from {where}: {reason}. Pass --weights DIR, a folder holding a "
        "CLIPModel, its tokenizer and image processor (save_pretrained of each)."
    )
    return EncoderError(msg)
