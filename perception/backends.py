"""Backend registry: which detector, segmenter, image encoder and point encoder the config names, where
their weights live, and whether they are present.

    det, seg = make_detector(settings, cell)          # geometric | llmdet | grounding-dino  x  geometric | sam2
    img = make_image_encoder(settings)                 # none | colour | dinov2 | beit | clip
    pts = make_point_encoder(settings.point_encoder)   # fpfh | a plug-in (see plugins.py)

Learned backends load through `transformers` from ``<settings.weights_dir>/<checkpoint folder>`` and never
download anything; a missing or broken folder raises ``MissingWeightsError`` naming the checkpoint, the
expected layout and the command that fetches it on a connected machine. ``backend_status`` reports all of
this for `kitchenbot models`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from kitchenbot.perception.detect import Detector, Segmenter
    from kitchenbot.perception.features import ImageEncoder, PointEncoder
    from kitchenbot.perception.settings import PerceptionSettings
    from kitchenbot.world.cell import Cell

DETECTORS = ("geometric", "llmdet", "grounding-dino")
SEGMENTERS = ("geometric", "sam2")
IMAGE_ENCODERS = ("none", "colour", "dinov2", "beit", "clip")


class BackendError(ValueError):
    """An unknown backend name, or a backend that cannot run here (missing packages)."""


class MissingWeightsError(FileNotFoundError):
    """A learned backend's weights folder is missing or incomplete."""


@dataclass(frozen=True)
class Checkpoint:
    """A Hugging Face checkpoint a learned backend loads (from a local folder only)."""

    backend: str  # the name in the config
    role: str  # detector | segmenter | image_encoder
    repo_id: str  # Hugging Face id, for fetching on a connected machine
    folder: str  # folder name under weights_dir
    model_class: str  # transformers class that loads it
    model_types: tuple[str, ...]  # accepted config.json "model_type" values
    needs_tokenizer: bool = False

    def path(self, weights_dir: str | Path) -> Path:
        return Path(weights_dir).expanduser() / self.folder

    def fetch_command(self, weights_dir: str | Path) -> str:
        # `hf` is huggingface_hub's CLI (older releases call it `huggingface-cli download`, same arguments)
        return f"hf download {self.repo_id} --local-dir {self.path(weights_dir)}"

    def layout(self) -> str:
        files = ["config.json", "model.safetensors (or sharded model-*.safetensors + index)"]
        if self.needs_tokenizer:
            files.append("tokenizer files (tokenizer.json or vocab.txt, tokenizer_config.json)")
        files.append("preprocessor_config.json (optional: input size, mean/std)")
        return ", ".join(files)


CHECKPOINTS: dict[str, Checkpoint] = {
    c.backend: c
    for c in (
        Checkpoint("llmdet", "detector", "iSEE-Laboratory/llmdet_tiny", "llmdet_tiny",
                   "MMGroundingDinoForObjectDetection", ("mm-grounding-dino",), needs_tokenizer=True),
        Checkpoint("grounding-dino", "detector", "IDEA-Research/grounding-dino-tiny", "grounding-dino-tiny",
                   "GroundingDinoForObjectDetection", ("grounding-dino",), needs_tokenizer=True),
        Checkpoint("sam2", "segmenter", "facebook/sam2.1-hiera-tiny", "sam2.1-hiera-tiny", "Sam2Model", ("sam2",)),
        Checkpoint("dinov2", "image_encoder", "facebook/dinov2-small", "dinov2-small", "Dinov2Model", ("dinov2",)),
        Checkpoint("beit", "image_encoder", "microsoft/beit-base-patch16-224-pt22k", "beit-base-patch16-224-pt22k",
                   "BeitModel", ("beit",)),
        Checkpoint("clip", "image_encoder", "openai/clip-vit-base-patch16", "clip-vit-base-patch16",
                   "CLIPVisionModel", ("clip", "clip_vision_model")),
    )
}


def learned_available() -> str | None:
    """None when torch and transformers import; otherwise why not (for error messages)."""
    try:
        import torch  # noqa: F401
        import transformers  # noqa: F401
    except ImportError as e:
        return (f"{e.name} is not installed: learned backends need `pip install torch==2.13.0` (the CPU build) "
                "and then `pip install -e .[learned]`")
    return None


def _weights_problem(ck: Checkpoint, weights_dir: str | Path) -> str | None:
    """None when the folder looks loadable, else what is wrong with it."""
    p = ck.path(weights_dir)
    if not p.is_dir():
        return f"{p} does not exist"
    cfg = p / "config.json"
    if not cfg.is_file():
        return f"{cfg} is missing"
    try:
        model_type = json.loads(cfg.read_text()).get("model_type")
    except (OSError, json.JSONDecodeError) as e:
        return f"{cfg} is not readable JSON ({e})"
    if model_type not in ck.model_types:
        return f"{cfg} says model_type {model_type!r}, expected {' or '.join(map(repr, ck.model_types))}"
    if not (p / "model.safetensors").is_file() and not (p / "model.safetensors.index.json").is_file():
        return f"{p} has no model.safetensors (nor model.safetensors.index.json)"
    if ck.needs_tokenizer and not any((p / f).is_file() for f in ("tokenizer.json", "vocab.txt")):
        return f"{p} has no tokenizer (tokenizer.json or vocab.txt)"
    return None


def weights_error(ck: Checkpoint, weights_dir: str | Path, problem: str) -> MissingWeightsError:
    return MissingWeightsError(
        f"perception.{ck.role} {ck.backend!r} needs the checkpoint {ck.repo_id} in {ck.path(weights_dir)}: {problem}. "
        f"Expected layout: {ck.layout()}. Fetch it on a connected machine with "
        f"`{ck.fetch_command(weights_dir)}` (older huggingface_hub: `huggingface-cli download`, same arguments) "
        "and copy the folder here (or set perception.weights_dir).")


def checkpoint_dir(backend: str, weights_dir: str | Path) -> Path:
    """The local folder of a learned backend's checkpoint; raises MissingWeightsError when unusable."""
    ck = CHECKPOINTS[backend]
    problem = _weights_problem(ck, weights_dir)
    if problem:
        raise weights_error(ck, weights_dir, problem)
    return ck.path(weights_dir)


def _check_name(field: str, name: str, choices: tuple[str, ...]) -> None:
    if name not in choices:
        raise BackendError(f"perception.{field}: unknown backend {name!r}; choose one of {', '.join(choices)}")


def _require_learned(field: str, name: str) -> None:
    why = learned_available()
    if why:
        raise BackendError(f"perception.{field} {name!r}: {why}")


# ---- factories --------------------------------------------------------------------------------------------
def make_detector(settings: "PerceptionSettings", cell: "Cell | None") -> tuple["Detector", "Segmenter"]:
    """The configured detector and segmenter. The geometric segmenter needs the geometric detector's masks
    only when it is also the detector; a learned detector with the 'geometric' segmenter keeps the geometric
    masks that fall inside its boxes (see ``BoxFilteredGeometric``)."""
    from kitchenbot.perception.detect import PassThroughSegmenter
    from kitchenbot.perception.segment_geometric import GeometricSegmenter

    _check_name("detector", settings.detector, DETECTORS)
    _check_name("segmenter", settings.segmenter, SEGMENTERS)
    if settings.detector == "geometric":
        det = GeometricSegmenter(cell)
    else:
        _require_learned("detector", settings.detector)
        from kitchenbot.perception.hf_detectors import GroundedDetector

        det = GroundedDetector.from_settings(settings.detector, settings)
    if settings.segmenter == "sam2":
        _require_learned("segmenter", "sam2")
        from kitchenbot.perception.hf_sam2 import Sam2Segmenter

        return det, Sam2Segmenter(checkpoint_dir("sam2", settings.weights_dir))
    if isinstance(det, GeometricSegmenter):
        return det, PassThroughSegmenter()
    from kitchenbot.perception.hf_detectors import BoxFilteredGeometric

    return det, BoxFilteredGeometric(GeometricSegmenter(cell))


def make_image_encoder(settings: "PerceptionSettings") -> "ImageEncoder | None":
    """The configured image encoder (None for 'none'); `settings.fusion=False` keeps its class tokens for the
    candidate proposal but takes its patch tokens out of the fused features (the paper's "without fusion")."""
    from kitchenbot.perception import features

    name = settings.image_encoder
    _check_name("image_encoder", name, IMAGE_ENCODERS)
    if name not in CHECKPOINTS:  # weight-free: none | colour (features.py)
        enc = features.make_image_encoder(name)
        if enc is None:
            return None
    else:
        _require_learned("image_encoder", name)
        from kitchenbot.perception.hf_encoders import HFImageEncoder

        enc = HFImageEncoder(name, checkpoint_dir(name, settings.weights_dir))
    if not getattr(settings, "fusion", True):
        from kitchenbot.perception.hf_encoders import ClassTokenOnly

        enc = ClassTokenOnly(enc)
    return enc


def make_point_encoder(name: str) -> "PointEncoder":
    from kitchenbot.perception.plugins import load_point_encoder

    return load_point_encoder(name)


# ---- status (for `kitchenbot models` and the sweep) --------------------------------------------------------
@dataclass
class BackendStatus:
    role: str
    name: str
    checkpoint: str  # repo id, or "-" for weight-free backends
    path: str  # where the weights are expected, or "-"
    available: bool
    reason: str = ""  # why not available


def backend_available(name: str, weights_dir: str | Path) -> tuple[bool, str]:
    """(usable here, why not) for any backend name of any role."""
    if name not in CHECKPOINTS:
        return True, ""
    problem = _weights_problem(CHECKPOINTS[name], weights_dir)
    if problem:
        return False, f"weights missing: {problem}"
    why = learned_available()
    return (why is None), (why or "")


def backend_status(weights_dir: str | Path) -> list[BackendStatus]:
    from kitchenbot.perception.plugins import point_encoder_names

    out: list[BackendStatus] = []
    for role, names in (("detector", DETECTORS), ("segmenter", SEGMENTERS), ("image_encoder", IMAGE_ENCODERS)):
        for n in names:
            ok, why = backend_available(n, weights_dir)
            ck = CHECKPOINTS.get(n)
            out.append(BackendStatus(role, n, ck.repo_id if ck else "-", str(ck.path(weights_dir)) if ck else "-", ok, why))
    for n, origin in point_encoder_names().items():
        out.append(BackendStatus("point_encoder", n, origin, "-", True, ""))
    return out


def detect_and_segment(detector: "Detector", segmenter: "Segmenter", views: list) -> list[list]:
    """Detections with masks for every view. Backends with `detect_batch` / `segment_batch` (the learned ones)
    get all views in one call, so the GPU sees one batch per scan; others run view by view."""
    if hasattr(detector, "detect_batch"):
        boxes = detector.detect_batch(views)
    else:
        boxes = [detector.detect(v) for v in views]
    if hasattr(segmenter, "segment_batch"):
        return segmenter.segment_batch(views, boxes)
    return [segmenter.segment(v, b) for v, b in zip(views, boxes)]
