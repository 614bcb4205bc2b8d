"""One typed configuration, built from ``params.yaml`` and validated before any work starts."""

from __future__ import annotations

import copy
import dataclasses
import os
import types
import typing
import urllib.parse
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal, Sequence, get_args, get_origin

from msdepth.config.checks import (
    SHOWN_CHARS,
    Range,
    check,
    check_per_pixel_costs,
    check_ranges,
    convert_scalar,
    shown,
)
from msdepth.config.network_sizes import TRAINING_SIDES, sides_problem
from msdepth.config.params_yaml import parse
from msdepth.config.variants import (
    configs as variant_configs,  # light: the loss variants' configs, not their terms
)
from msdepth.errors import ConfigError, DataError
from msdepth.readers import not_regular_file, open_regular

# The ranges of the checks below that bound a value only so that it cannot fail later.
SEED_MAX = 2**32 - 1  # numpy's legacy seeding (np.random.seed) takes seeds below 2^32
MAX_SIZE = 4096  # px, network input and render size (KITTI: 375 x 1242)
MAX_WIDTH_MULTIPLIER = 4.0  # 1.0 = the dissertation's ~31 M parameters; 4.0 about 16 times that
MAX_DIST_TIMEOUT_S = 86_400.0  # a day; Python's timedelta (torch.distributed) overflows far above
# The outer bounds of every other number (each field declares its Range; check_ranges enforces it):
# far beyond any sensible value, and small enough that none exhausts memory, time or the process table.
MAX_THREADS = max(4, 4 * (os.cpu_count() or 1))  # torch.set_num_threads(10**6) broke process creation
MAX_FRAMES = 1_000_000  # frames, pairs or drives of a set (KITTI's raw data: ~47,000 frames)
MAX_CARS = 12  # cars a rendered street draws (each tried 20 times for a free spot)
MAX_STEPS = 1_000_000  # optimiser steps or steps between host reads
MAX_EPOCHS = 10_000
MAX_BATCH = 4096
MAX_LEARNING_RATE = 10.0  # Adam moves each parameter by about the rate per step
# Below this a float32 parameter of 0.01 moves by under its own rounding step (eps 1.2e-7 x 0.01):
# Adam changes nothing, so 1e-320 (which passed as > 0) is a typo.
MIN_LEARNING_RATE = 1e-9
MAX_WEIGHT = 1e4  # a loss term's weight (the defaults: 0.1 to 30)
MAX_DEPTH_M = 10_000.0  # metres (KITTI's GT ends at ~80 m)
MAX_CROP_SCALE = 4  # train.crop_scale: 4 = 1/16 of the image per crop
MAX_NPROC = 1024  # torchrun's processes per node
MAX_SOURCE_OFFSET = 100  # frames between a monocular target and its sources (Monodepth2: 1)
MAX_JOBS = 64  # parallel downloads
MAX_BOOTSTRAP_SAMPLES = 1_000_000  # resamples x rows of float64 per interval (10^12 asked 7 TiB)

Seed = Annotated[int, Range(0, SEED_MAX)]
Threads = Annotated[int, Range(1, MAX_THREADS, note="4 per CPU core, at least 4")]
Frames = Annotated[int, Range(0, MAX_FRAMES)]  # 0 = all or none, as each field says
Steps = Annotated[int, Range(1, MAX_STEPS)]
Weight = Annotated[float, Range(0, MAX_WEIGHT)]
Fraction = Annotated[float, Range(0, 1)]
LearningRate = Annotated[float, Range(MIN_LEARNING_RATE, MAX_LEARNING_RATE, note="Adam's step per update")]
WidthMultiplier = Annotated[float, Range(0, MAX_WIDTH_MULTIPLIER, low_open=True)]
InitDisparity = Annotated[float, Range(0, 0.3, low_open=True, high_open=True, note="the heads' range")]
Depth = Annotated[float, Range(0, MAX_DEPTH_M, low_open=True, note="metres")]
SourceOffset = Annotated[int, Range(-MAX_SOURCE_OFFSET, MAX_SOURCE_OFFSET)]


def _speed_only(default: Any) -> Any:
    """A TrainConfig field that only changes speed (see :func:`speed_only_train_keys`)."""
    return field(default=default, metadata={"speed_only": True})


def _list_may_be_empty(default: tuple) -> Any:
    """A tuple field whose YAML list may be empty (every other list must name something)."""
    return field(default=default, metadata={"may_be_empty": True})


def _regular_file_problem(path: str | os.PathLike) -> str | None:
    """What keeps ``path`` from being a readable regular file ("no such file", "a folder, not a
    file", "not a regular file ...", "cannot open it (...)"), None if it is one. ``os.stat``, not
    ``Path.is_file``: the latter raises on a name too long; a FIFO is not opened, so never blocks."""
    try:
        info = os.stat(path)
    except FileNotFoundError:
        return "no such file"
    except OSError as exc:  # a name too long, a symbolic link loop, no permission on a folder
        return f"cannot open it ({exc.strerror or exc})"
    return not_regular_file(info.st_mode)


def _added_later(default: Any) -> Any:
    """A field added after checkpoints existed: at its default it is left out of the training
    fingerprint (:func:`fingerprint_fields`), so those checkpoints keep theirs."""
    return field(default=default, metadata={"fingerprint_omits_default": True})


@dataclass(frozen=True)
class CameraConfig:
    """The photometric camera each rendered view passes through (:mod:`msdepth.render.sensor`).

    Defaults are calibrated against real KITTI pairs at the render width (the ``photometry`` stage,
    docs/design.md "The camera"); ``enabled: false`` gives the ideal views of earlier releases, byte
    for byte.
    """

    enabled: bool = True
    # Where each default comes from (docs/design.md "The camera"; measured: the photometry stage).
    # A lens's point-spread function: ~0.6 px at KITTI's full width, a third of it at the render width.
    blur: Annotated[float, Range(0, 10, note="px at the render width")] = 0.2
    # Light lost at the corners: the cos^4 law at KITTI's 40 deg half field of view, as a corrected
    # lens passes it.
    vignetting: Annotated[float, Range(0, 0.9, note="light lost at the image corners")] = 0.3
    # A rig's rectification residual: ~1 px at KITTI's full width.
    rectification: Annotated[float, Range(0, 5, note="px")] = 0.3
    # Auto-exposure target; with the scenes' lower contrast, it puts KITTI's mean grey and spread within 15 %.
    exposure: Annotated[float, Range(0.01, 1, note="the left view's mean, of full scale")] = 0.43
    # KITTI's two cameras expose on their own: their views' mean grey levels differ by 1-7 levels of 255.
    gain_mismatch: Annotated[float, Range(0, 1, note="log-normal sigma")] = 0.04
    white_balance: Annotated[float, Range(0, 1, note="log-normal sigma")] = 0.02
    # Read and shot noise, calibrated on KITTI's noise sigma and SSIM at the GT disparity.
    read_noise: Annotated[float, Range(0, 64, note="DN of 255")] = 2.0
    shot_noise: Annotated[float, Range(0, 64, note="DN of 255 at full scale")] = 4.5
    jpeg_quality: Annotated[int, Range(0, 100, note="0 = PNG")] = 0


@dataclass(frozen=True)
class SyntheticConfig:
    """The generated KITTI-format stereo set."""

    seed: Seed = 2017
    drives: Annotated[int, Range(1, MAX_FRAMES)] = 12
    train_pairs: Annotated[int, Range(1, MAX_FRAMES)] = 1200
    eval_frames: Annotated[int, Range(1, MAX_FRAMES)] = 40
    height: Annotated[int, Range(32, MAX_SIZE)] = 125
    width: Annotated[int, Range(64, MAX_SIZE)] = 414
    # Evaluation GT beyond this depth is left invalid (0), as KITTI's LiDAR-based GT has no
    # points past its range (~80 m); 0 keeps every rendered surface.
    gt_max_depth: Annotated[float, Range(0, MAX_DEPTH_M, note="metres; 0 = no limit")] = 80.0
    # > 0: each drive's training frames are sequences of this many frames, each one static scene
    # seen by a rig moving forward (Monodepth2's monocular training); 0 = independent frames.
    sequence_length: Frames = _added_later(0)
    # The training frames' cars: how many a frame draws, [min, max], and how far ahead their
    # centres lie, metres. More and nearer than the evaluation street's 0-6 at 4-40 m
    # (msdepth.render.cars.CAR_COUNT / CAR_DEPTH, kept so scores stay comparable): the networks then
    # find cars within the default's budget (issue 52's screen, studies/results/objects/).
    train_cars: tuple[Annotated[int, Range(0, MAX_CARS)], ...] = (3, 8)
    train_car_depth: tuple[Annotated[float, Range(4, MAX_DEPTH_M)], ...] = (4.0, 25.0)
    # The camera that records each view (off: the ideal views of earlier releases, byte for byte).
    camera: CameraConfig = field(default_factory=CameraConfig)

    def validate(self, key: str, params: Params) -> None:
        """Range checks of the ``key`` section; a ConfigError names the key."""
        for name in ("train_cars", "train_car_depth"):
            low_high = getattr(self, name)
            check(
                len(low_high) == 2 and low_high[0] <= low_high[1],
                f"{key}.{name}",
                f"must be [min, max] with min <= max, got {list(low_high)}",
            )
        check(
            self.sequence_length == 0 or self.sequence_length >= 3,
            f"{key}.sequence_length",
            f"must be 0 (none) or >= 3 (a frame with neighbours on both sides), got {self.sequence_length}",
        )
        for name in ("drives", "train_pairs", "eval_frames"):
            check(getattr(self, name) >= 1, f"{key}.{name}", "must be >= 1")
        check(0 <= self.seed <= SEED_MAX, f"{key}.seed", f"must be in 0..{SEED_MAX}, got {self.seed}")
        check(self.drives <= self.train_pairs, f"{key}.drives", "must not exceed train_pairs")
        check(self.height >= 32 and self.width >= 64, f"{key}.height", "render size must be at least 32 x 64")
        for name in ("height", "width"):
            size = getattr(self, name)
            check(size <= MAX_SIZE, f"{key}.{name}", f"must be <= {MAX_SIZE} (px), got {size}")
        check(
            self.gt_max_depth >= 0,
            f"{key}.gt_max_depth",
            f"must be >= 0 (0 = no limit), got {self.gt_max_depth}",
        )


@dataclass(frozen=True)
class KittiConfig:
    """Real KITTI: where to fetch it, what to fetch, which splits and ROIs to use."""

    base_url: str = "https://s3.eu-central-1.amazonaws.com/avg-kitti/"
    allow_http: bool = False  # plain http only for a mirror you trust: anyone on the path can swap archives
    # The drives fetched are those the train split and eval.extra_sets' lists name; these restrict further.
    drives: tuple[str, ...] | None = None  # None = every needed drive; or those of the list that are needed
    drive_count: Frames = 0  # > 0: only the first N needed drives (to start small)
    jobs: Annotated[int, Range(1, MAX_JOBS)] = 4  # parallel connections
    jpeg: bool = False  # convert extracted PNGs to JPEG (quality 92), as Monodepth did
    download_dir: str = "data/downloads"
    archive_list: str = "data_lists/kitti_archives_to_download.txt"
    scene_flow_archive: str = "data_scene_flow.zip"  # KITTI 2015 (evaluation frames and GT)
    train_split: str = "data_lists/kitti_train_files.txt"
    eval_split: str = "data_lists/kitti_stereo_2015_test_files.txt"
    eigen_split: str = "data_lists/eigen_test_files.txt"  # 697 frames, raw-LiDAR GT
    eigen_benchmark_split: str = "data_lists/eigen_benchmark_test_files.txt"  # 652, annotated depth GT
    depth_annotated: str = "depth_annotated"  # below data.root: data_depth_annotated.zip's train/ and val/
    # KITTI's annotated depth (~14 GB), fetched only for eval.extra_sets' eigen_benchmark
    depth_annotated_archive: str = "data_depth_annotated.zip"
    # train.mode mono | mono_stereo: Monodepth2's eigen_zhou split of raw frames (``drive frame
    # side``), whose drives are fetched too; and KITTI odometry (data_odometry_color.zip's
    # sequences/<NN>/image_2 with data_odometry_poses.zip's poses/<NN>.txt, below data.root, not
    # fetched) for the pose ATE on the sequences named, when they are there.
    mono_split: str = _added_later("data_lists/eigen_zhou_train_files.txt")
    odometry: str = _added_later("odometry")
    odometry_sequences: tuple[str, ...] = _added_later(("09", "10"))
    # hand-drawn boxes (image, class, x0, y0, x1, y1) on KITTI 2015 frames, added to the obj_map cars
    # (the evaluation frames of data.source kitti, and eval.extra_sets' kitti2015)
    rois_csv: str = ""
    # eval.extra_sets' kitti2012: boxes on its training frames, the same format (it has no obj_map)
    kitti2012_rois_csv: str = _added_later("")
    roi_min_size: Annotated[int, Range(1, MAX_SIZE)] = 16  # px, both sides of an automatic car box
    roi_min_valid: Fraction = 0.3  # fraction of an automatic car box with valid GT

    def validate(self, key: str, params: Params) -> None:
        """Range checks of the ``key`` section; a ConfigError names the key."""
        check(self.drive_count >= 0, f"{key}.drive_count", f"must be >= 0 (0 = all), got {self.drive_count}")
        check(self.jobs >= 1, f"{key}.jobs", f"must be >= 1, got {self.jobs}")
        check(self.roi_min_size >= 1, f"{key}.roi_min_size", f"must be >= 1, got {self.roi_min_size}")
        check(
            0 <= self.roi_min_valid <= 1,
            f"{key}.roi_min_valid",
            f"must be in [0, 1], got {self.roi_min_valid}",
        )
        check(
            self.drives is None or not self.drive_count,
            f"{key}.drive_count",
            "give either drives or drive_count, not both",
        )
        check(
            # two ASCII digits (KITTI's are 00..21): a name becomes a file name, which has a length limit
            all(s.isascii() and s.isdigit() and len(s) == 2 for s in self.odometry_sequences),
            f"{key}.odometry_sequences",
            f"must be KITTI odometry sequence numbers of two digits like '09', "
            f"got {shown(list(self.odometry_sequences))}",
        )
        scheme = urllib.parse.urlsplit(self.base_url).scheme.lower()
        refused = (
            f"plain http is refused unless {key}.allow_http is true (a mirror you trust), "
            f"got {shown(self.base_url)}"
            if scheme == "http"
            else f"must be an https URL, got {shown(self.base_url)}"
        )
        check(scheme == "https" or (scheme == "http" and self.allow_http), f"{key}.base_url", refused)


@dataclass(frozen=True)
class FolderConfig:
    """Any rectified stereo set in one folder (msdepth.data.folder): paths relative to it."""

    # "" = data.root. The pipeline tracks the data as ${data.root} (dvc.yaml), so the folder must
    # be data.root: any other value is refused by validate() with that hint. Beside another source,
    # the folder of eval.extra_sets' "folder" (required there; its other keys apply as here).
    root: str = ""
    left: str = "left"  # left images ...
    right: str = "right"  # ... and right images of the same file names
    pairs: str = ""  # "" = pair the two folders; else a file of "left right" relative paths
    camera: str = "camera.yaml"  # focal_px at width_px, baseline_m
    eval_list: str = "eval.txt"  # "left right [gt]" per evaluation frame; never trained on
    npy_is_disparity: bool = False  # .npy GT holds disparity in px (else depth in m)
    rois_csv: str = ""  # boxes on the evaluation frames, the format of data.kitti.rois_csv
    class_maps: str = ""  # "" = none; a folder of <frame>.png label maps and classes.yaml naming them

    def validate(self, key: str, params: Params) -> None:
        """``data.source: folder``: the folder's keys, and what the folder cannot provide."""
        root = shown(self.root)
        suggested = root[1:-1] if root[0] == root[-1] else root  # without the quotes, unless elided
        check(
            self.root in ("", params.data.root),
            f"{key}.root",
            f"must be empty (= data.root) or data.root itself, got {root}: the pipeline tracks the data "
            f"as data.root (dvc.yaml), so set data.root: {suggested} instead",
        )
        if not self.pairs:
            for name in ("left", "right"):
                check(
                    bool(getattr(self, name)),
                    f"{key}.{name}",
                    f"must name a folder when {key}.pairs is empty",
                )
            check(
                self.left != self.right, f"{key}.right", f"must differ from {key}.left ({shown(self.left)})"
            )
        check(
            bool(self.camera), f"{key}.camera", "must name the camera file (focal_px, width_px, baseline_m)"
        )
        check(
            bool(self.eval_list),
            f"{key}.eval_list",
            "must name the evaluation list ('left right [gt]' lines)",
        )
        check(
            not params.eval.extra_sets,
            "eval.extra_sets",
            f"{list(params.eval.extra_sets)} need KITTI raw data, which data.source folder has not: "
            "set eval.extra_sets: []",
        )


@dataclass(frozen=True)
class DataConfig:
    source: Literal["synthetic", "kitti", "folder"] = "synthetic"
    # Each source its own tree (msdepth.data.owners): data/synthetic here; KITTI: data/kitti.
    root: str = "data/synthetic"
    height: Annotated[int, Range(TRAINING_SIDES.minimum, MAX_SIZE)] = 64
    width: Annotated[int, Range(TRAINING_SIDES.minimum, MAX_SIZE)] = 192
    gt: Literal["disp_noc_0", "disp_occ_0"] = "disp_noc_0"
    synthetic: SyntheticConfig = field(default_factory=SyntheticConfig)
    kitti: KittiConfig = field(default_factory=KittiConfig)
    folder: FolderConfig = field(default_factory=FolderConfig)

    def validate(self, key: str, params: Params) -> None:
        """Range checks of the ``key`` section and its subsections; a ConfigError names the key."""
        rule = TRAINING_SIDES
        for name in ("height", "width"):
            size = getattr(self, name)
            check(
                rule.fits(size),
                f"{key}.{name}",
                f"must be a multiple of {rule.multiple} and >= {rule.minimum}, got {size}",
            )
            check(size <= MAX_SIZE, f"{key}.{name}", f"must be <= {MAX_SIZE} (px), got {size}")
        self.synthetic.validate(f"{key}.synthetic", params)
        self.kitti.validate(f"{key}.kitti", params)
        if self.source == "folder":
            self.folder.validate(f"{key}.folder", params)


@dataclass(frozen=True)
class ModelConfig:
    width_multiplier: WidthMultiplier = 0.25
    init_disparity: InitDisparity = 0.04
    # none = the dissertation's conv + ELU network; group = a GroupNorm after every convolution
    norm: Literal["none", "group"] = "group"
    # independent = the dissertation's heads; residual = each finer scale corrects the coarser one
    heads: Literal["independent", "residual"] = "residual"
    # The pose network's width (train.mode mono | mono_stereo); 1.0 = Monodepth2's ResNet-18.
    pose_width_multiplier: WidthMultiplier = _added_later(0.25)
    # The depth network: vgg = the dissertation's (Monodepth's); resnet18 = Monodepth2's.
    architecture: Literal["vgg", "resnet18"] = _added_later("vgg")
    # "" = from scratch; or a torchvision resnet18 state dict a user downloaded, for every ResNet
    # encoder of the run (resnet18's depth encoder, the monocular modes' pose encoder).
    pretrained: str = _added_later("")

    def validate(self, key: str, params: Params) -> None:
        """Range checks of the ``key`` section; a ConfigError names the key."""
        self._validate_widths(key)
        check(
            0 < self.init_disparity < 0.3,
            f"{key}.init_disparity",
            "must be in (0, 0.3) (heads output 0.3*sigmoid)",
        )
        for side in ("height", "width"):  # data.validate checked the training rule; a network may be stricter
            value = getattr(params.data, side)
            rule = sides_problem(self.architecture, [value])
            if rule is not None:
                raise ConfigError(
                    f"data.{side}: model.architecture {self.architecture} needs a multiple of "
                    f"{rule.multiple}, at least {rule.minimum}, got {value}"
                )
        if self.pretrained:
            self._validate_pretrained(key, params)

    def _validate_pretrained(self, key: str, params: Params) -> None:
        """``pretrained`` names a file, and every ResNet encoder it loads into has ResNet-18's width."""
        encoders = [("width_multiplier", self.architecture == "resnet18")]
        encoders.append(("pose_width_multiplier", params.train.mode != "stereo"))
        check(
            any(used for _, used in encoders),
            f"{key}.pretrained",
            "the run has no ResNet encoder to load it into (model.architecture resnet18 or train.mode "
            'mono | mono_stereo); set it to ""',
        )
        for name, used in encoders:
            value = getattr(self, name)
            check(
                not used or value == 1.0,
                f"{key}.{name}",
                f"must be 1.0 with model.pretrained (a torchvision ResNet-18's width), got {value}",
            )
        problem = _regular_file_problem(self.pretrained)
        check(problem is None, f"{key}.pretrained", f"{problem}: {self.pretrained}")

    def _validate_widths(self, key: str) -> None:
        """Both width multipliers in (0, MAX_WIDTH_MULTIPLIER]."""
        for name, full in (
            ("width_multiplier", "the dissertation's"),
            ("pose_width_multiplier", "Monodepth2's"),
        ):
            multiplier = getattr(self, name)
            check(multiplier > 0, f"{key}.{name}", "must be > 0")
            check(
                multiplier <= MAX_WIDTH_MULTIPLIER,
                f"{key}.{name}",
                f"must be <= {MAX_WIDTH_MULTIPLIER} (1.0 = {full} network), got {multiplier}",
            )


@dataclass(frozen=True)
class TrainConfig:
    # One training run per variant and seed; each seed seeds init, shuffling and augmentation.
    seeds: tuple[Seed, ...] = (0, 1, 2)
    epochs: Annotated[int, Range(1, MAX_EPOCHS)] = 8
    batch_size: Annotated[int, Range(1, MAX_BATCH)] = 8
    # 3e-4, not the dissertation's 1e-4: over the default's 1,200 steps it lowers the car error on
    # every seed screened (studies/results/objects/); 1e-4 suits Monodepth's ~180k steps.
    learning_rate: LearningRate = 3e-4
    # step = Monodepth's (lr, /2 after 3/5 of the steps, /4 after 4/5); cosine = a linear warm-up
    # over the first 5 % of the steps, then a cosine decay to 0 (issue 52's screen).
    schedule: Literal["step", "cosine"] = _added_later("step")
    # 1 = the network trains on the whole image at data.height x data.width; s > 1 = the images are
    # resized to s times that, the network trains on random data.height x data.width crops of them
    # (each object s times the pixels at the same cost per step) and infers on the whole image.
    crop_scale: Annotated[int, Range(1, MAX_CROP_SCALE)] = _added_later(1)
    num_workers: Annotated[int, Range(0, MAX_THREADS, note="4 per CPU core, at least 4")] = _speed_only(0)
    augment: bool = True
    device: Literal["cpu", "cuda", "auto"] = _speed_only("cpu")
    # torch's CPU threads split its reductions differently, so the count changes float rounding
    # (weights by ~1e-7, benchmarks/README.md); a checkpoint still resumes at another count.
    threads: Threads = _speed_only(2)
    # Speed switches for a GPU (all off on the CPU default). The loss is always computed in fp32;
    # amp changes the network's arithmetic, so it is not speed-only.
    amp: Literal["none", "bf16"] = "none"
    channels_last: bool = _speed_only(False)
    compile: bool = _speed_only(False)
    # cuDNN picks its convolution algorithms by timing them (fixed input size: once per shape).
    # CUDA only; GPU runs are not bit-repeatable anyway (grid_sample's backward adds atomically).
    cudnn_benchmark: bool = _speed_only(True)
    # Steps between reads of the loss on the host (non-finite check, progress bar, epoch means);
    # 0 = automatic: every step on the CPU, every 50 on a GPU, whose queue each read drains.
    sync_every: Annotated[int, Range(0, MAX_STEPS)] = _speed_only(0)
    # Data parallel: `torchrun` runs nproc processes (batch_size is per process, so nproc
    # changes the global batch and is not speed-only).
    launcher: Literal["local", "torchrun"] = _speed_only("local")
    nproc: Annotated[int, Range(1, MAX_NPROC)] = 1
    # A collective waiting longer (a dead rank) is an error.
    dist_timeout_s: Annotated[float, Range(0, MAX_DIST_TIMEOUT_S, low_open=True)] = _speed_only(600.0)
    # stereo = Monodepth (left-right pairs); mono / mono_stereo = Monodepth2's M / MS
    # (msdepth.losses.monocular), which need frame sequences: data.synthetic.sequence_length > 0.
    mode: Literal["stereo", "mono", "mono_stereo"] = _added_later("stereo")
    # Monodepth2's source frames of the monocular modes, as offsets from the target frame.
    source_frames: tuple[SourceOffset, ...] = _added_later((-1, 1))

    @property
    def monocular(self) -> bool:
        """Whether the runs are Monodepth2's M or MS: their depth is up to scale, evaluated median-scaled."""
        return self.mode != "stereo"

    def validate(self, key: str, params: Params) -> None:
        """Range checks of the ``key`` section; a ConfigError names the key."""
        check(self.epochs >= 1, f"{key}.epochs", "must be >= 1")
        check(self.batch_size >= 1, f"{key}.batch_size", "must be >= 1")
        check(self.learning_rate > 0, f"{key}.learning_rate", f"must be > 0, got {self.learning_rate}")
        check(self.num_workers >= 0, f"{key}.num_workers", "must be >= 0")
        check(self.nproc >= 1, f"{key}.nproc", f"must be >= 1, got {self.nproc}")
        check(
            self.sync_every >= 0, f"{key}.sync_every", f"must be >= 0 (0 = automatic), got {self.sync_every}"
        )
        timeout = self.dist_timeout_s
        check(timeout > 0, f"{key}.dist_timeout_s", "must be > 0")
        check(
            timeout <= MAX_DIST_TIMEOUT_S, f"{key}.dist_timeout_s", f"must be <= {MAX_DIST_TIMEOUT_S:g} (s)"
        )
        check(
            self.mode == "stereo" or self.crop_scale == 1,
            f"{key}.crop_scale",
            f"applies to train.mode stereo only (frame sequences are not cropped), got {self.crop_scale}",
        )
        check(
            max(params.image_size) <= MAX_SIZE,
            f"{key}.crop_scale",
            f"data.height and data.width times {self.crop_scale} must be <= {MAX_SIZE} px",
        )
        frames = list(self.source_frames)
        check(
            0 not in frames and len(set(frames)) == len(frames),
            f"{key}.source_frames",
            f"must be distinct non-zero offsets from the target frame, got {shown(frames)}",
        )
        check(
            self.mode != "stereo" or frames == [-1, 1],
            f"{key}.source_frames",
            f"applies to train.mode mono and mono_stereo only; keep [-1, 1] in stereo, got {shown(frames)}",
        )
        rendered = params.data.source == "synthetic" and params.data.synthetic.sequence_length > 0
        check(
            self.mode == "stereo" or rendered or params.data.source == "kitti",
            f"{key}.mode",
            f"{shown(self.mode)} trains on frame sequences: KITTI's raw drives (data.source kitti) or "
            f"rendered ones (data.source synthetic with data.synthetic.sequence_length >= 3; here "
            f"data.source is {params.data.source} and sequence_length "
            f"{params.data.synthetic.sequence_length}), or set train.mode stereo",
        )
        seeds = list(self.seeds)
        in_range = all(0 <= seed <= SEED_MAX for seed in seeds)
        check(in_range, f"{key}.seeds", f"must be in 0..{SEED_MAX}, got {shown(seeds)}")
        check(len(set(seeds)) == len(seeds), f"{key}.seeds", f"must not repeat a seed, got {shown(seeds)}")


def speed_only_train_keys() -> tuple[str, ...]:
    """The ``train.*`` keys that change how fast a run goes, not what it computes beyond float
    rounding (``threads`` changes the rounding; the others on the CPU, nothing): a checkpoint
    stays valid when they change (the training fingerprint leaves them out)."""
    return tuple(f.name for f in dataclasses.fields(TrainConfig) if f.metadata.get("speed_only"))


def fingerprint_fields(cfg: Any) -> dict[str, Any]:
    """``dataclasses.asdict(cfg)`` without the fields marked :func:`_added_later` that are at their
    default: what the training fingerprint hashes of a config section."""
    values = dataclasses.asdict(cfg)
    for f in dataclasses.fields(cfg):
        if f.metadata.get("fingerprint_omits_default") and values[f.name] == f.default:
            del values[f.name]
    return values


@dataclass(frozen=True)
class LossConfig:
    alpha: Fraction = 0.85  # appearance = alpha*(1-S)/2 + (1-alpha)*L1 of the SSIM-type terms
    smoothness_weight: Weight = 0.1
    lr_weight: Weight = 1.0
    padding_mode: Literal["border", "zeros"] = "border"
    # SSIM/MS-SSIM arithmetic: fast = msdepth.losses.ssim_kernels, reference = the written-out autograd
    # formula (same values up to rounding; a fallback, and what the fast kernels are tested against).
    kernels: Literal["fast", "reference"] = _added_later("fast")
    # Monodepth2's full-resolution multi-scale loss: each scale's disparity is upsampled to the
    # input size before warping, so every scale's appearance and left-right terms are at full size
    # (smoothness stays at the scale's own size).
    full_resolution: bool = _added_later(False)

    def validate(self, key: str, params: Params) -> None:
        """Range checks of the ``key`` section; a ConfigError names the key."""
        check(0 <= self.alpha <= 1, f"{key}.alpha", "must be in [0, 1]")
        check(self.smoothness_weight >= 0, f"{key}.smoothness_weight", "must be >= 0")
        check(self.lr_weight >= 0, f"{key}.lr_weight", "must be >= 0")


def _variant_configs() -> dict[str, type]:
    """Every registered loss variant's config class by name (:mod:`msdepth.config.variants`); a variant
    named like a section of :class:`Params` is a programming error."""
    registered = dict(variant_configs())
    clash = sorted(set(registered) & {f.name for f in dataclasses.fields(Params)})
    if clash:
        raise ValueError(f"variant(s) {clash}: the name of a params section that is not a variant")
    return registered


def _registered_sections() -> dict[str, Any]:
    """Default config of every registered loss variant (:mod:`msdepth.config.variants`)."""
    return {name: config() for name, config in _variant_configs().items()}


@dataclass(frozen=True)
class EvalConfig:
    caps: tuple[Depth, ...] = (80.0, 50.0)
    min_depth: Depth = 1e-3
    mask_gt_beyond_cap: bool = False
    post_process: bool = True
    dense_gt_fraction: Annotated[float, Range(0, 1, low_open=True)] = 0.9
    # Evaluated beside KITTI 2015 (which always runs: the dissertation's tables), each under
    # metrics/sets/<set>/ (msdepth.data.eval_sets): the full-image suite, where kitti2012 adds its
    # exact class "reflective" and kitti2015 "car" where it has obj_map (msdepth.evaluation.classes),
    # and the ROI suite on the set's boxes (kitti2015: obj_map cars and data.kitti.rois_csv;
    # kitti2012: data.kitti.kitti2012_rois_csv; msdepth.data.rois.set_roi_boxes). "folder": the
    # stereo folder of data.folder.* (root: that folder) beside another source, its class maps and
    # boxes with it.
    extra_sets: tuple[Literal["eigen", "eigen_benchmark", "kitti2012", "kitti2015", "folder"], ...] = (
        _list_may_be_empty(("eigen",))
    )
    median_scaling: bool = False  # per-image median scaling of the extra sets (Monodepth2's mono evaluation)

    def validate(self, key: str, params: Params) -> None:
        """Range checks of the ``key`` section; a ConfigError names the key."""
        check(
            all(c > self.min_depth for c in self.caps),
            f"{key}.caps",
            f"every cap must exceed {key}.min_depth",
        )
        check(self.min_depth > 0, f"{key}.min_depth", "must be > 0")
        check(0 < self.dense_gt_fraction <= 1, f"{key}.dense_gt_fraction", "must be in (0, 1]")
        sets = list(self.extra_sets)
        check(len(set(sets)) == len(sets), f"{key}.extra_sets", f"must not repeat a set, got {shown(sets)}")
        check(
            "folder" not in sets or bool(params.data.folder.root),
            "data.folder.root",
            f"must name the stereo folder that {key}.extra_sets' folder evaluates on",
        )


@dataclass(frozen=True)
class CompareConfig:
    reference: str = "ssim"  # every other run is compared with this variant
    bootstrap_samples: Annotated[int, Range(100, MAX_BOOTSTRAP_SAMPLES)] = 10_000
    confidence: Annotated[float, Range(0, 1, low_open=True, high_open=True)] = 0.95
    seed: Seed = 0

    def validate(self, key: str, params: Params) -> None:
        """Range checks of the ``key`` section; a ConfigError names the key."""
        check(
            self.reference in params.variants,
            f"{key}.reference",
            f"{shown(self.reference)} is not a variant; configured: {list(params.variants)}",
        )
        check(0 < self.confidence < 1, f"{key}.confidence", f"must be in (0, 1), got {self.confidence}")
        check(0 <= self.seed <= SEED_MAX, f"{key}.seed", f"must be in 0..{SEED_MAX}, got {self.seed}")


# The optimum's starts (msdepth.optimum.starts): a constant, SGM on the variant's own cost volume, SGBM.
OptimumStart = Literal["constant", "cost", "sgbm"]
OPTIMUM_STARTS: tuple[str, ...] = get_args(OptimumStart)


# The optimum's memory is about 0.7 GB per megapixel of working size (a 1-megapixel pair peaks 0.74 GB
# above a 48 x 128 one, levels 1, on a 2-core AMD EPYC): a side of
# 4096 px keeps a square pair near 12 GB; more levels than 12 halve any such side below 1 px.
MAX_OPTIMUM_SIDE = 4096
MAX_OPTIMUM_LEVELS = 12
MAX_OPTIMUM_BATCH = 64
MAX_WIDTH_DEFAULT = 640  # optimum.max_width: KITTI's 1242 px halved, the render's 414 px kept
MIN_MAX_WIDTH = 64  # a cap below it would leave the coarsest level under SSIM's windows
OptimumLevels = Annotated[int, Range(1, MAX_OPTIMUM_LEVELS)]


def _check_workers(key: str, jobs: int, threads: int) -> None:
    """An extra set stage's torch threads, all jobs together, within :data:`MAX_THREADS` (``jobs``
    and ``threads`` out of range on their own get their own line from the range check)."""
    in_range = max(jobs, threads) <= MAX_THREADS
    check(
        not in_range or jobs * threads <= MAX_THREADS,
        key,
        f"times threads must be <= {MAX_THREADS}, got {jobs * threads}",
    )


@dataclass(frozen=True)
class OptimumConfig:
    """The losses' own optimum (:mod:`msdepth.optimum.solver`): per stereo pair, the disparity maps that
    minimise a variant's training objective, optimised directly (no network; docs/optimum.md)."""

    # coarse-to-fine levels, each half the size of the next (fewer if the image is small)
    levels: OptimumLevels = 3
    # Adam steps per level: the stopping rule. 50 fits the pipeline's time budget; the measured rule
    # is 100, which ``msdepth optimum`` uses without a params file (docs/optimum.md).
    iterations: Steps = 50
    learning_rate: LearningRate = 0.05  # Adam's, on the logit of disparity / 0.3 (the network heads' range)
    init_disparity: InitDisparity = 0.04  # the constant start, fraction of the width
    # constant: coarse to fine from init_disparity; cost/sgbm: a matched start (msdepth.optimum.starts),
    # refined by refine_iterations Adam steps at each of the finest refine_levels levels (docs/optimum.md).
    start: OptimumStart = "cost"
    refine_levels: OptimumLevels = 2
    refine_iterations: Steps = 50
    height: Annotated[int, Range(0, MAX_OPTIMUM_SIDE)] = 0  # working size; 0 = data.synthetic's render size
    width: Annotated[int, Range(0, MAX_OPTIMUM_SIDE)] = 0  # (the CLI: the image's own)
    # The widest the matcher and the solver work at: a wider working size is worked at its largest
    # halving within it and the result resized back (0: no cap). At half of KITTI's 1242 px the
    # optimum agrees with full size within 0.013 abs_rel at a quarter of the time (docs/optimum.md).
    max_width: Annotated[int, Range(0, MAX_OPTIMUM_SIDE)] = MAX_WIDTH_DEFAULT
    # Its own weight, not loss.smoothness_weight: a network regularises implicitly, a per-pixel
    # map does not. Results are reported at every weight of smoothness_sweep (a decade or more).
    smoothness_weight: Weight = 10.0
    smoothness_sweep: tuple[Annotated[float, Range(0, MAX_WEIGHT, low_open=True)], ...] = (3.0, 10.0, 30.0)
    # The weights of eval.extra_sets' optimum (each a stage per set and variant): smoothness_weight
    # alone by default, the lean run; the sweep on your sets is one param away (= smoothness_sweep).
    set_weights: tuple[Annotated[float, Range(0, MAX_WEIGHT, low_open=True)], ...] = _added_later((10.0,))
    # 0: the weights as given at any working size. N: they hold at a working width of N px and
    # scale by W / N at width W (the smoothness term falls as 1 / W; docs/optimum.md, measured).
    # 414: the render width, where the weights were chosen, so the pipeline's results keep them.
    smoothness_width: Annotated[int, Range(0, MAX_OPTIMUM_SIDE)] = 414
    # pairs optimised together (independent: each pair's gradient is its own)
    batch_size: Annotated[int, Range(1, MAX_OPTIMUM_BATCH)] = 4
    # The pipeline's optimum stages (docs/optimum-pipeline.md): the sweep's weights other than
    # smoothness_weight see only the first sweep_frames evaluation frames (0 = all: each loss is
    # then also scored at its own best weight, msdepth.optimum.selection), the cost
    # curves the ROIs of the first cost_frames; torch threads.
    sweep_frames: Frames = 0
    cost_frames: Frames = 8
    threads: Threads = 2
    # An extra set's frames in this many worker processes at once, each with `threads` threads
    # (a frame's result depends on `threads` only). 2 x 1 thread on 2 cores: benchmarks/README.md.
    jobs: Threads = 1

    def validate(self, key: str, params: Params) -> None:
        """Range checks of the ``key`` section; a ConfigError names the key."""
        for name in ("levels", "refine_levels"):  # each level halves the size: more than 12 leave < 1 px
            value = getattr(self, name)
            check(
                1 <= value <= MAX_OPTIMUM_LEVELS,
                f"{key}.{name}",
                f"must be in 1..{MAX_OPTIMUM_LEVELS}, got {value}",
            )
        check(self.iterations >= 1, f"{key}.iterations", f"must be >= 1, got {self.iterations}")
        check(self.learning_rate > 0, f"{key}.learning_rate", f"must be > 0, got {self.learning_rate}")
        check(
            0 < self.init_disparity < 0.3,
            f"{key}.init_disparity",
            f"must be in (0, 0.3) (the heads' range), got {self.init_disparity}",
        )
        batch = self.batch_size
        check(
            1 <= batch <= MAX_OPTIMUM_BATCH,
            f"{key}.batch_size",
            f"must be in 1..{MAX_OPTIMUM_BATCH}, got {batch}",
        )
        steps = self.refine_iterations
        check(steps >= 1, f"{key}.refine_iterations", f"must be >= 1, got {steps}")
        check(self.smoothness_weight >= 0, f"{key}.smoothness_weight", "must be >= 0")
        width = self.smoothness_width
        check(width >= 0, f"{key}.smoothness_width", f"must be 0 (not scaled) or a width in px, got {width}")
        check(self.sweep_frames >= 0, f"{key}.sweep_frames", f"must be >= 0, got {self.sweep_frames}")
        check(self.cost_frames >= 0, f"{key}.cost_frames", f"must be >= 0, got {self.cost_frames}")
        _check_workers(f"{key}.jobs", self.jobs, self.threads)
        check_per_pixel_costs(f"{key}.start", self.start, {v: params.appearance[v] for v in params.variants})
        sweep = self.smoothness_sweep
        check(
            min(sweep) > 0 and max(sweep) >= 10 * min(sweep) and self.smoothness_weight in sweep,
            f"{key}.smoothness_sweep",
            f"must be positive, span at least a decade and hold smoothness_weight, got {list(sweep)}",
        )
        weights = list(self.set_weights)
        check(
            self.smoothness_weight in weights and min(weights) > 0 and len(set(weights)) == len(weights),
            f"{key}.set_weights",
            f"must be positive, distinct and hold smoothness_weight ({self.smoothness_weight:g}), "
            f"got {weights}",
        )
        cap = self.max_width
        check(
            cap == 0 or MIN_MAX_WIDTH <= cap <= MAX_OPTIMUM_SIDE,
            f"{key}.max_width",
            f"must be 0 (no cap) or in {MIN_MAX_WIDTH}..{MAX_OPTIMUM_SIDE} px, got {cap}",
        )
        for name in ("height", "width"):
            size = getattr(self, name)
            check(
                size == 0 or 24 <= size <= MAX_OPTIMUM_SIDE,
                f"{key}.{name}",
                f"must be 0 (default) or in 24..{MAX_OPTIMUM_SIDE} px, got {size}",
            )


@dataclass(frozen=True)
class PhotometryConfig:
    """The ``photometry`` stage: how the evaluation frames look to a photometric loss, beside real pairs."""

    # Per-frame statistics of real pairs (``msdepth photometry``), the stage's real column.
    reference: str = "data_lists/photometry_kitti.csv"

    def validate(self, key: str, params: Params) -> None:
        """The reference must name a file (the stage depends on it); a ConfigError names the key."""
        problem = "must name a CSV file of `msdepth photometry`"
        check(bool(self.reference.strip()), f"{key}.reference", problem)


@dataclass(frozen=True)
class Params:
    data: DataConfig = field(default_factory=DataConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    # A loss variant is named after its params section, so that DVC can track exactly that
    # section per stage; each registered variant (msdepth.config.variants) has one.
    variants: tuple[str, ...] = ("ssim", "msssim")
    eval: EvalConfig = field(default_factory=EvalConfig)
    compare: CompareConfig = field(default_factory=CompareConfig)
    optimum: OptimumConfig = field(default_factory=OptimumConfig)
    photometry: PhotometryConfig = field(default_factory=PhotometryConfig)
    # The params section of every registered variant, by name (top-level sections in
    # params.yaml, e.g. ``ssim:``; not a key of its own).
    appearance: dict[str, Any] = field(default_factory=_registered_sections, metadata={"yaml": False})

    def __getattr__(self, name: str) -> Any:
        # ``params.ssim``: a variant's section reads like the other sections.
        sections = self.__dict__.get("appearance", {})
        if not name.startswith("_") and name in sections:
            return sections[name]
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @property
    def image_size(self) -> tuple[int, int]:
        """(height, width) the images are resized to: the trained network infers at it, the pair
        cache holds it, and training crops data.height x data.width from it (``train.crop_scale``).

        Example:
            >>> Params().image_size
            (64, 192)
        """
        scale = self.train.crop_scale
        return self.data.height * scale, self.data.width * scale

    def variant(self, name: str) -> str:
        """The variant called ``name``, or a ConfigError listing the configured ones."""
        if name not in self.variants:
            raise ConfigError(f"variants: unknown variant {shown(name)}; configured: {list(self.variants)}")
        return name

    def seed(self, value: str | int) -> int:
        """The training seed ``value`` (e.g. a stage's argument), or a ConfigError if not in train.seeds."""
        try:
            seed = int(value)
        except ValueError:
            raise ConfigError(f"train.seeds: {shown(value)} is not an integer seed") from None
        if seed not in self.train.seeds:
            raise ConfigError(
                f"train.seeds: seed {seed} is not listed; configured: {shown(list(self.train.seeds))}"
            )
        return seed


def _convert(value: Any, tp: Any, key: str) -> Any:
    """Convert a YAML value to type ``tp`` or raise a ConfigError naming ``key``."""
    origin = get_origin(tp)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"{key}: expected a mapping, got {type(value).__name__}")
        return _build(tp, value, key)
    if origin is Literal:
        if value not in get_args(tp):
            raise ConfigError(f"{key}: {shown(value)} is not one of {list(get_args(tp))}")
        return value
    if origin is tuple:
        (inner, _) = get_args(tp)
        if not isinstance(value, (list, tuple)) or not value:
            raise ConfigError(f"{key}: expected a non-empty list, got {shown(value)}")
        return tuple(_convert(v, inner, f"{key}[{i}]") for i, v in enumerate(value))
    if origin is dict:
        _, inner = get_args(tp)
        if not isinstance(value, dict) or not value:
            raise ConfigError(f"{key}: expected a non-empty mapping, got {shown(value)}")
        return {str(k): _convert(v, inner, f"{key}.{k}") for k, v in value.items()}
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in get_args(tp):
            return None
        (inner,) = [a for a in get_args(tp) if a is not type(None)]
        return _convert(value, inner, key)
    return convert_scalar(value, tp, key)


def _build(cls: type, raw: dict, prefix: str) -> Any:
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls) if f.metadata.get("yaml", True)}
    for name in raw:  # YAML reads an unquoted 1, ~ or true as a number, null or boolean
        check(isinstance(name, str), prefix or "top level", f"key {shown(name)} is not a parameter name")
    unknown = set(raw) - names
    if unknown:
        where = f"{prefix}." if prefix else ""
        raise ConfigError(f"unknown parameter(s) {shown(sorted(where + u for u in unknown))}")
    empty_ok = {f.name for f in dataclasses.fields(cls) if f.metadata.get("may_be_empty")}
    kwargs = {
        name: ()
        if name in empty_ok and raw[name] == []
        else _convert(raw[name], hints[name], f"{prefix}.{name}" if prefix else name)
        for name in names
        if name in raw
    }
    return cls(**kwargs)


def validate(p: Params) -> Params:
    """Range checks that types alone cannot express, section by section; raises ConfigError naming the key."""
    for i, name in enumerate(p.variants):
        check(name in p.appearance, f"variants[{i}]", f"{shown(name)} is not one of {list(p.appearance)}")
    p.data.validate("data", p)
    p.model.validate("model", p)
    p.train.validate("train", p)
    variants = list(p.variants)
    check(len(set(variants)) == len(variants), "variants", f"must not repeat a variant, got {variants}")
    p.loss.validate("loss", p)
    # Each trained variant's config checks its own section (types and unknown keys are checked for
    # every section; the range checks of a section no run uses, e.g. against the image size, wait).
    for name in p.variants:
        p.appearance[name].validate(name, p)
    p.eval.validate("eval", p)
    p.compare.validate("compare", p)
    p.optimum.validate("optimum", p)
    p.photometry.validate("photometry", p)
    # Last, so that a value with a check of its own gets that check's message.
    for f in dataclasses.fields(p):
        section = getattr(p, f.name)
        if dataclasses.is_dataclass(section):
            check_ranges(section, f.name)
    for name, section in p.appearance.items():
        check_ranges(section, name)
    return p


def params_from_dict(raw: dict) -> Params:
    """Build and validate :class:`Params` from a parsed params.yaml mapping."""
    if not isinstance(raw, dict):
        raise ConfigError("params: expected a mapping at the top level")
    registered = _variant_configs()
    sections = {name: _convert(raw.get(name, {}), config, name) for name, config in registered.items()}
    params = _build(Params, {k: v for k, v in raw.items() if k not in registered}, "")
    return validate(dataclasses.replace(params, appearance=sections))


def apply_overrides(raw: dict, assignments: Sequence[str]) -> dict:
    """``raw`` (a parsed params.yaml) with each ``a.b.c=value`` (a YAML value) set, creating
    sections as needed: ``--set`` of ``msdepth optimum`` and of the studies' scripts."""
    for item in assignments:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"--set: expected KEY=VALUE, got {shown(item)}")
        node = raw
        *parents, last = key.split(".")
        for part in parents:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ConfigError(f"--set {_cut(item)}: {shown(part)} is not a section")
        try:
            node[last] = parse(value)
        except ConfigError as exc:  # the assignment is echoed cut: it may be any length
            problem = str(exc).removeprefix("top level: ")
            raise ConfigError(f"--set {_cut(item)}: {problem}") from None
    return raw


def _cut(text: str) -> str:
    """``text`` on one line, cut to about SHOWN_CHARS characters."""
    text = " ".join(text.splitlines())
    return text if len(text) <= SHOWN_CHARS else f"{text[: SHOWN_CHARS - 3]}..."


def kernel_variant(raw: dict, spec: str) -> tuple[str, dict]:
    """A studies' variant spec, ``name`` or ``name:K`` (the variant with ``kernel_size`` K), as
    ``(name, a copy of raw with that kernel size set)``; ``raw`` itself is left as it is."""
    name, _, kernel = spec.partition(":")
    out = copy.deepcopy(raw)
    if kernel:
        try:
            out.setdefault(name, {})["kernel_size"] = int(kernel)
        except ValueError:
            raise ConfigError(f"variant {shown(spec)}: expected NAME or NAME:KERNEL_SIZE") from None
    return name, out


MAX_PARAMS_BYTES = 1 << 20  # params.yaml is about 10 KB; a file this large is not one


def load_params(path: str | os.PathLike = "params.yaml", overrides: Sequence[str] = ()) -> Params:
    """Read ``params.yaml`` (:func:`read_params_file`), with the ``--set`` ``overrides``
    (:func:`apply_overrides`), into a validated :class:`Params` (one ConfigError naming the key)."""
    raw = read_params_file(path)
    try:
        return params_from_dict(apply_overrides(raw, overrides))
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def read_params_file(path: str | os.PathLike = "params.yaml") -> dict:
    """The hardened reading of a params file as plain data: at most MAX_PARAMS_BYTES, UTF-8, no
    alias, duplicate key or long integer (:func:`msdepth.config.params_yaml.parse`), a mapping at the
    top level (empty file: ``{}``). Every refusal is one ConfigError naming the file."""
    path = Path(path)
    try:  # a regular file only (a FIFO blocked the read forever); its size is checked below
        with open_regular(path, "params", allow_empty=True) as file:
            data = file.read(MAX_PARAMS_BYTES + 1)
    except DataError as exc:
        raise ConfigError(str(exc)) from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from None
    try:
        check(
            len(data) <= MAX_PARAMS_BYTES,
            "file",
            f"larger than {MAX_PARAMS_BYTES >> 20} MiB: not a params file",
        )
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError as exc:
            line = data.count(b"\n", 0, exc.start) + 1
            raise ConfigError(f"not UTF-8 text (byte 0x{data[exc.start]:02x} on line {line})") from None
        raw = parse(text)
        check(raw is None or isinstance(raw, dict), "params", "expected a mapping at the top level")
        return {} if raw is None else raw
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
