"""The ``onnx`` descriptor: a learned global descriptor (NetVLAD, CosPlace, MixVPR, ...) from an ONNX file.

The model is data, not code: ONNX Runtime (the only run-time dependency; no PyTorch)
evaluates its graph, and nothing in the file can execute Python. The file's SHA-256 is
written to the run's ``/log`` and ``metrics.json`` beside the execution providers used,
so a run names exactly which weights produced it.

Each frame goes through the typed preprocessing the model was trained with
(:class:`Preprocessing`: size or "keep aspect, multiple of N", resampling, colour order,
scale, mean and standard deviation, NCHW or NHWC), one inference, the chosen output
flattened, an optional projection (PCA or whitening, a ``.npy`` matrix) and an optional
L2 normalisation. The distance the vectors are compared by (``cosine`` or ``l2``) is part
of the config and travels with every ``Features`` message, so detectors follow it.
:meth:`OnnxDescriptor.describe_many` runs images in batches of at most ``batch_size``
(a run hands the descriptor one frame at a time, so a run's calls hold one image).
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Sequence
from functools import cached_property
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from slamfront import DataError, Descriptor, PluginConfig, PluginError, StageInputs
from slamfront.lazy import lazy_module
from slamfront.limits import over_limit
from slamfront.messages import Features

cv2 = lazy_module("cv2")  # loads on first use: listing plugins imports neither
ort = lazy_module("onnxruntime")

logger = logging.getLogger(__name__)

PREFERRED_PROVIDERS = ("TensorrtExecutionProvider", "CUDAExecutionProvider", "CPUExecutionProvider")
"""``providers: auto`` takes those of these that the installed ONNX Runtime has, in this order."""

_INTERPOLATION = {"nearest": "INTER_NEAREST", "bilinear": "INTER_LINEAR", "bicubic": "INTER_CUBIC",
                  "area": "INTER_AREA", "lanczos": "INTER_LANCZOS4"}


class Preprocessing(PluginConfig):
    """How a frame becomes the model's input tensor (what the model was trained with)."""

    width: int = Field(224, ge=1, description="input width in pixels (size: fixed)")
    height: int = Field(224, ge=1, description="input height in pixels (size: fixed)")
    size: Literal["fixed", "keep_aspect"] = Field(
        "fixed", description="fixed: resize to width x height; keep_aspect: short side to short_side, both sides "
        "rounded to a multiple of multiple_of (for models with a free input size)"
    )
    short_side: int = Field(224, ge=1, description="keep_aspect: the short side's length before rounding")
    multiple_of: int = Field(1, ge=1, description="keep_aspect: both sides rounded to a multiple of this (ViTs: 14)")
    resize: Literal["nearest", "bilinear", "bicubic", "area", "lanczos"] = Field(
        "bilinear", description="resampling (OpenCV's)"
    )
    colour: Literal["rgb", "bgr", "grey"] = Field("rgb", description="channel order the model expects")
    scale: float = Field(1 / 255, gt=0, description="pixel values are multiplied by this before mean and std")
    mean: tuple[float, ...] = Field((0.485, 0.456, 0.406), description="per-channel mean subtracted (ImageNet's)")
    std: tuple[float, ...] = Field((0.229, 0.224, 0.225), description="per-channel divisor (ImageNet's)")
    layout: Literal["nchw", "nhwc"] = Field("nchw", description="tensor layout (PyTorch exports: nchw)")

    @property
    def channels(self) -> int:
        return 1 if self.colour == "grey" else 3

    @model_validator(mode="after")
    def _statistics_per_channel(self) -> Preprocessing:
        for name in ("mean", "std"):
            if len(getattr(self, name)) != self.channels:
                raise ValueError(f"{name} needs {self.channels} values for colour: {self.colour}")
        if any(s <= 0 for s in self.std):
            raise ValueError("std values must be greater than 0")
        return self

    def input_size(self, height: int, width: int) -> tuple[int, int]:
        """(height, width) of the tensor made from an image of ``height`` x ``width``."""
        if self.size == "fixed":
            return self.height, self.width
        factor = self.short_side / min(height, width)
        n = self.multiple_of
        return tuple(max(n, int(round(side * factor / n)) * n) for side in (height, width))  # type: ignore[return-value]

    def tensor(self, image: np.ndarray) -> np.ndarray:
        """One (C, H, W) or (H, W, C) float32 input of an (H, W) or (H, W, 3) RGB uint8 image."""
        if self.colour == "grey":
            pixels = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        else:
            pixels = np.repeat(image[:, :, None], 3, axis=2) if image.ndim == 2 else image
            if self.colour == "bgr":
                pixels = pixels[:, :, ::-1]
        height, width = self.input_size(*image.shape[:2])
        if (height, width) != pixels.shape[:2]:
            flag = getattr(cv2, _INTERPOLATION[self.resize])
            pixels = cv2.resize(np.ascontiguousarray(pixels), (width, height), interpolation=flag)
        pixels = pixels.reshape(height, width, self.channels).astype(np.float32) * np.float32(self.scale)
        pixels = (pixels - np.asarray(self.mean, np.float32)) / np.asarray(self.std, np.float32)
        return np.ascontiguousarray(pixels.transpose(2, 0, 1) if self.layout == "nchw" else pixels)


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as stream:
        for block in iter(lambda: stream.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _readable_file(path: Path, what: str) -> Path:
    """``path`` when it is a readable file (for field validators: the error names the field)."""
    if not path.is_file():
        raise ValueError(f"{what} {path} does not exist or is not a file")
    try:
        with path.open("rb"):
            pass
    except OSError as exc:
        raise ValueError(f"{what} {path} cannot be read: {exc.strerror}") from None
    return path


class OnnxDescriptor(Descriptor):
    """A learned global descriptor from an ONNX model, run by ONNX Runtime (CPU; CUDA or TensorRT when present).

    Bring a NetVLAD (Arandjelovic 2016), CosPlace (Berton 2022), EigenPlaces (Berton 2023),
    MixVPR (Ali-bey 2023), SALAD (Izquierdo 2024) or MegaLoc (Berton 2025) model exported to
    ONNX, with the preprocessing it was trained with. Refused before the first frame: a missing or unreadable
    model, a model larger than ``SLAMFRONT_LIMITS`` ``model_bytes``, input or output shapes
    that do not fit the preprocessing; at a frame: NaN or infinite outputs.
    """

    name = "onnx"
    produces_global = True

    class Config(PluginConfig):
        model: Path = Field(description="the .onnx file (data: its SHA-256 is logged)")
        preprocessing: Preprocessing = Field(default_factory=Preprocessing, description="frame -> input tensor")
        output: str | None = Field(None, description="the graph output that is the descriptor (default: the first)")
        projection: Path | None = Field(
            None, description="optional (D, K) .npy matrix applied after the model (PCA, whitening)"
        )
        projection_mean: Path | None = Field(None, description="optional (D,) .npy vector subtracted before projection")
        l2_normalise: bool = Field(True, description="scale each vector to unit length (after the projection)")
        metric: Literal["cosine", "l2"] = Field("cosine", description="how the model's vectors are compared")
        batch_size: int = Field(16, ge=1, le=1024, description="most images per inference call (describe_many)")
        providers: Literal["auto", "cpu"] = Field(
            "auto", description="auto: TensorRT, CUDA, CPU, those installed; cpu: CPU only"
        )
        threads: int = Field(0, ge=0, le=256, description="CPU threads of one inference (0: ONNX Runtime's choice)")

        @field_validator("model")
        @classmethod
        def _model_fits(cls, path: Path) -> Path:
            _readable_file(path, "model file")
            problem = over_limit("model_bytes", path.stat().st_size, f"model file {path}")
            if problem:
                raise ValueError(problem)
            return path

        @field_validator("projection", "projection_mean")
        @classmethod
        def _array_file(cls, path: Path | None) -> Path | None:
            return None if path is None else _readable_file(path, "array file")

    def __init__(self, config: Config | None = None) -> None:
        super().__init__(config)
        self._announced = False

    # -- the model ---------------------------------------------------------------------------

    @cached_property
    def sha256(self) -> str:
        return file_sha256(self.config.model)

    @cached_property
    def session(self) -> Any:
        """The ONNX Runtime session, its shapes checked against the preprocessing."""
        c = self.config
        options = ort.SessionOptions()
        options.intra_op_num_threads = c.threads
        options.inter_op_num_threads = 1
        options.log_severity_level = 3  # errors only: ORT's own warnings are not ours to print
        available = ort.get_available_providers()
        wanted = ["CPUExecutionProvider"] if c.providers == "cpu" else [p for p in PREFERRED_PROVIDERS
                                                                         if p in available]
        try:
            session = ort.InferenceSession(str(c.model), sess_options=options, providers=wanted)
        except Exception as exc:  # ORT raises its own types for every malformed file
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise DataError(f"model {c.model}: not a readable ONNX model ({first})") from None
        self._check_shapes(session)
        return session

    def _check_shapes(self, session: Any) -> None:
        c, p = self.config, self.config.preprocessing
        inputs = session.get_inputs()
        if len(inputs) != 1:
            raise PluginError(f"model {c.model}: has {len(inputs)} inputs; a descriptor model takes one image tensor")
        shape = list(inputs[0].shape)
        if len(shape) != 4:
            raise PluginError(f"model {c.model}: input {inputs[0].name!r} has shape {shape}; expected 4 dimensions "
                              f"({p.layout.upper()})")
        axes = dict(zip("chw" if p.layout == "nchw" else "hwc", shape[1:], strict=True))
        if isinstance(axes["c"], int) and axes["c"] != p.channels:
            raise PluginError(f"model {c.model}: input has {axes['c']} channels; preprocessing colour: {p.colour} "
                              f"gives {p.channels} (layout {p.layout})")
        for side, wanted in (("h", p.height), ("w", p.width)):
            fixed = axes[side]
            if isinstance(fixed, int) and (p.size == "keep_aspect" or fixed != wanted):
                asked = "a size kept from each image" if p.size == "keep_aspect" else f"{p.width}x{p.height}"
                raise PluginError(f"model {c.model}: input is fixed at {axes['w']}x{axes['h']} (width x height); "
                                  f"preprocessing asks {asked}")
        outputs = [o.name for o in session.get_outputs()]
        if c.output is not None and c.output not in outputs:
            raise PluginError(f"model {c.model}: has no output {c.output!r} (outputs: {', '.join(outputs)})")
        self._input = inputs[0].name
        self._output = c.output or outputs[0]
        batch = shape[0]
        if isinstance(batch, int) and batch != 1:
            raise PluginError(f"model {c.model}: its batch dimension is fixed at {batch}; export it as 1 or dynamic")
        self._max_batch = 1 if isinstance(batch, int) else c.batch_size

    @cached_property
    def _projection(self) -> tuple[np.ndarray, np.ndarray | None] | None:
        c = self.config
        if c.projection is None:
            return None
        matrix = _load_array(c.projection, "projection", 2)
        mean = None if c.projection_mean is None else _load_array(c.projection_mean, "projection_mean", 1)
        if mean is not None and mean.shape[0] != matrix.shape[0]:
            raise PluginError(f"projection_mean {c.projection_mean}: {mean.shape[0]} values for a projection of "
                              f"{matrix.shape[0]} rows")
        return matrix, mean

    @property
    def providers(self) -> list[str]:
        """The execution providers the session runs on, preferred first."""
        return list(self.session.get_providers())

    def check(self, stages: Any) -> None:
        _ = self.session, self._projection  # every refusal that needs no frame, before the first frame

    # -- describing ----------------------------------------------------------------------------

    def describe_many(self, images: Sequence[np.ndarray]) -> np.ndarray:
        """(n, D) float32 descriptors of n images, in inference calls of at most ``batch_size`` images
        (images of different input sizes go in separate calls)."""
        session = self.session
        out: list[np.ndarray] = []
        start = 0
        while start < len(images):
            first = self.config.preprocessing.tensor(images[start])
            batch = [first]
            while (len(batch) < self._max_batch and start + len(batch) < len(images)):
                tensor = self.config.preprocessing.tensor(images[start + len(batch)])
                if tensor.shape != first.shape:
                    break
                batch.append(tensor)
            result = session.run([self._output], {self._input: np.stack(batch)})[0]
            out.append(self._finish(np.asarray(result), start))
            start += len(batch)
        return np.concatenate(out) if out else np.empty((0, 0), np.float32)

    def describe(self, image: np.ndarray) -> np.ndarray:
        """(D,) float32 descriptor of one (H, W) or (H, W, 3) RGB uint8 image."""
        return self.describe_many([image])[0]

    def _finish(self, result: np.ndarray, first: int) -> np.ndarray:
        """Model outputs -> descriptors: flattened, checked, projected, normalised."""
        c = self.config
        vectors = result.reshape(result.shape[0], -1).astype(np.float64)
        if not np.isfinite(vectors).all():
            bad = first + int(np.flatnonzero(~np.isfinite(vectors).all(axis=1))[0])
            raise DataError(f"model {c.model}: output {self._output!r} is NaN or infinite for image {bad} of the "
                            "batch; the model or its preprocessing is wrong")
        projection = self._projection
        if projection is not None:
            matrix, mean = projection
            if matrix.shape[0] != vectors.shape[1]:
                raise PluginError(f"projection {c.projection}: {matrix.shape[0]} rows for a model output of "
                                  f"{vectors.shape[1]} values")
            vectors = (vectors - mean if mean is not None else vectors) @ matrix
        if c.l2_normalise:
            norms = np.linalg.norm(vectors, axis=1, keepdims=True)
            vectors = np.divide(vectors, norms, out=np.zeros_like(vectors), where=norms > 0)
        return vectors.astype(np.float32)

    def process(self, inputs: StageInputs) -> Sequence[Features]:
        if not self._announced:  # inside the run, so the line reaches its /log
            self._announced = True
            logger.info("onnx model %s sha256 %s, execution providers %s", self.config.model, self.sha256,
                        ", ".join(self.providers))
        frame = inputs.frame
        try:
            vector = self.describe(frame.image)
        except DataError as exc:
            raise DataError(f"frame {frame.index} ({frame.name or 'unnamed'}): {exc}") from None
        return [Features(frame=frame.index, vector=vector, metric=self.config.metric)]

    def statistics(self) -> dict[str, float | int | str]:
        """The model's SHA-256 and the execution providers used (for metrics.json and the report)."""
        return {"onnx_model_sha256": self.sha256, "onnx_providers": ",".join(self.providers)}


def _load_array(path: Path, field: str, ndim: int) -> np.ndarray:
    """A float ``.npy`` array of ``ndim`` dimensions (never unpickled)."""
    try:
        array = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise DataError(f"{field} {path}: not a readable .npy array ({exc})") from None
    if array.ndim != ndim or not np.issubdtype(array.dtype, np.number) or not np.isfinite(array).all():
        raise DataError(f"{field} {path}: expected a finite {ndim}-D numeric array, got {array.dtype} {array.shape}")
    return array.astype(np.float64)
