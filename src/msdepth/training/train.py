"""Training of one loss variant: Adam with Monodepth's schedule, per-epoch atomic checkpoints.

The loop resumes from the last complete checkpoint of the same configuration, so a killed
run continues where it stopped and ends with the same weights as an uninterrupted one.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import random
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch
from torch.nn.parallel import DistributedDataParallel
from torch.utils.data import DataLoader
from tqdm import tqdm

from msdepth.config.params import Params, TrainConfig, fingerprint_fields, speed_only_train_keys
from msdepth.data.pairs import StereoPairs, training_data_sha256
from msdepth.data.sequences import SequenceFrames, SequenceSample
from msdepth.errors import MsdepthError
from msdepth.io import write_json
from msdepth.losses.monocular import MonocularLoss, build_monocular_loss, monocular_losses
from msdepth.losses.monodepth import MonodepthLoss
from msdepth.losses.objective import build_loss
from msdepth.networks.common import MAX_DISPARITY
from msdepth.networks.device import one_pixel_wide_strided_convs, resolve_device
from msdepth.networks.model_file import (  # noqa: F401 - load_model: imported from here too
    DepthNetwork,
    depth_network,
    load_model,
    save_model,
)
from msdepth.networks.pose import PoseNet
from msdepth.networks.resnet import load_pretrained
from msdepth.networks.resnet_depth import ResNetMonodepth
from msdepth.networks.serialization import load_weights_file, save_weights_file
from msdepth.pipeline.paths import source_digest, source_files
from msdepth.readers import file_sha256
from msdepth.training import distributed
from msdepth.training.distributed import Context, GlobalBatchSampler
from msdepth.training.pairing import pairing_record

log = logging.getLogger(__name__)

WARMUP_FRACTION = 0.05  # train.schedule cosine: the warm-up's share of the steps
LOSS_KEYS = ("total", "appearance", "smoothness", "lr_consistency")
MONO_LOSS_KEYS = ("total", "appearance", "smoothness", "automask")  # train.mode mono and mono_stereo


class TrainingError(MsdepthError):
    """Training cannot go on (e.g. a non-finite loss); the message names the step and files."""


# TrainResult fields that depend on the machine and on interruptions, not on the params: kept
# out of the tracked training summary, so that a rerun leaves it (and `dvc metrics diff`) unchanged.
TIMING_KEYS = ("resumed_from_epoch", "seconds", "seconds_this_run", "examples_per_second")


@dataclass(frozen=True)
class TrainResult:
    steps: int  # in total, including those before a resume
    epochs: int
    resumed_from_epoch: int  # 0 = trained from scratch in this run
    seconds: float  # training time of all epochs, over every run that resumed the checkpoint
    seconds_this_run: float
    examples_per_second: float  # over all epochs
    final_losses: dict[str, float]


@dataclass(frozen=True)
class TrainOutputs:
    """Where :func:`train_variant` writes: the final weights (``model_path``), the checkpoint it
    writes after every epoch and resumes from (``checkpoint_path``), and, each only where given,
    dvclive's per-epoch losses (``live_dir``), the training summary (``summary_path``: steps, final
    losses, what the same params reproduce) and its timing (``timing_path``: seconds, examples/s,
    the epoch it resumed from, what varies between machines and interruptions)."""

    model_path: str | os.PathLike
    checkpoint_path: str | os.PathLike
    live_dir: str | os.PathLike | None = None
    summary_path: str | os.PathLike | None = None
    timing_path: str | os.PathLike | None = None


@dataclass(frozen=True, eq=False)
class TrainOptions:
    """What :func:`train_variant` may be given beyond the params: every field optional.

    - ``progress``: show a progress bar per epoch.
    - ``cache``: the pairs already resized (:func:`msdepth.data.pairs.build_pair_cache`); None:
      every sample is decoded and resized from the pairs.
    - ``seed``: the training seed; None: the first of ``train.seeds``.
    - ``on_epoch(epoch, model, mean_losses)``: called after each epoch trained in the call (epochs
      count from 1), e.g. to evaluate the network as it learns.
    - ``sequences``: the monocular modes' frame sequences (``train.mode`` mono or mono_stereo).
    - ``pretrained_sha256``: ``model.pretrained``'s content hash, for the fingerprint (the train
      stage's is the ``pretrained`` stage's record); None: the file is hashed by the run, so that
      even a resume needs it (see :func:`_resume_or_start`).
    """

    progress: bool = True
    cache: np.ndarray | None = None
    seed: int | None = None
    on_epoch: Callable[[int, DepthNetwork, dict[str, float]], None] | None = None
    sequences: Sequence[SequenceSample] | None = None
    pretrained_sha256: str | None = None


def _seed_everything(seed: int) -> None:
    """Seed Python, numpy and torch (CPU runs are then repeatable)."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def build_model(params: Params) -> DepthNetwork:
    """The depth network of ``params.model`` initialised for training (the VGG heads at
    ``init_disparity``); ``model.pretrained`` is loaded by :func:`_load_pretrained_encoders`, only
    into a run that starts fresh."""
    m = params.model
    return depth_network(m.architecture, m.width_multiplier, m.norm, m.heads, m.init_disparity)


def build_pose_net(params: Params) -> PoseNet:
    """The pose network of the monocular modes (Monodepth2's separate ResNet-18 pose network),
    initialised anew (``model.pretrained``: :func:`_load_pretrained_encoders`)."""
    return PoseNet(params.model.pose_width_multiplier)


def _load_pretrained_encoders(
    path: str | os.PathLike, model: DepthNetwork, pose_net: PoseNet | None = None, sha256: str | None = None
) -> None:
    """Load the torchvision resnet18 state dict at ``path`` (``model.pretrained``) into every ResNet
    encoder of a run: a resnet18 depth network's and the pose network's (a VGG network has none).

    With ``sha256`` the file must still hold that content, the one the checkpoint fingerprint
    names; a TrainingError says it changed since it was hashed.
    """
    if sha256 is not None and (found := file_sha256(path, "weights")) != sha256:
        raise TrainingError(
            f"{path}: content changed since it was hashed (sha256 {sha256[:12]}..., now {found[:12]}...); "
            "run `dvc repro` again to record and train on the new weights"
        )
    if isinstance(model, ResNetMonodepth):
        load_pretrained(model.encoder, path)
    if pose_net is not None:
        load_pretrained(pose_net.encoder, path)


def trained_pose_net(params: Params, checkpoint_path: str | os.PathLike) -> PoseNet:
    """The pose network of a monocular run's last checkpoint (the model file holds only the depth
    network), on the CPU, in eval mode; a TrainingError names a checkpoint without one."""
    state = _load_checkpoint(Path(checkpoint_path), torch.device("cpu"))
    if "pose" not in state:
        raise TrainingError(f"{checkpoint_path}: no pose network (not a train.mode mono | mono_stereo run)")
    net = build_pose_net(params)
    try:
        net.load_state_dict(state["pose"])
    except (RuntimeError, TypeError, AttributeError) as exc:  # wrong shapes or names: long messages
        what = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise TrainingError(f"{checkpoint_path}: a malformed checkpoint ({what})") from None
    return net.eval()


def learning_rate(base: float, step: int, total_steps: int, schedule: str = "step") -> float:
    """The learning rate of one optimiser step under ``train.schedule``.

    ``step`` is Monodepth's piecewise-constant schedule: lr, lr/2 after 3/5 of the steps, lr/4
    after 4/5. ``cosine`` warms up linearly over the first 5 % of the steps (at least one), then
    decays along a cosine from ``base`` to 0 at the last step.

    Args:
        base: the peak learning rate (``train.learning_rate``).
        step: the 0-based step.
        total_steps: the run's steps (epochs x steps per epoch).
        schedule: ``"step"`` or ``"cosine"``.

    Returns:
        The learning rate of ``step``.

    Example:
        >>> learning_rate(1e-4, 700, 1000)
        5e-05
        >>> [round(learning_rate(1.0, s, 100, "cosine"), 3) for s in (0, 4, 5, 52, 99)]
        [0.2, 1.0, 1.0, 0.5, 0.0]
    """
    if schedule == "cosine":
        warmup = max(1, round(WARMUP_FRACTION * total_steps))
        if step < warmup:
            return base * (step + 1) / warmup
        span = max(1, total_steps - 1 - warmup)
        return base * 0.5 * (1 + math.cos(math.pi * min(1.0, (step - warmup) / span)))
    if schedule != "step":
        raise ValueError(f"learning_rate: unknown schedule {schedule!r} (step | cosine)")
    boundaries = (int(3 / 5 * total_steps), int(4 / 5 * total_steps))
    if step < boundaries[0]:
        return base
    if step < boundaries[1]:
        return base / 2
    return base / 4


# The modules (and packages: every .py file below them) whose code shapes a training run, all in
# the train stage's code fingerprint, data/fingerprints/train.txt (a test keeps them there). Their
# bytes are part of the checkpoint fingerprint: when DVC reruns the stage because one changed, the run
# trains anew instead of resuming a checkpoint that the old code wrote, so a model always comes
# from the code that is committed with it. A new variant lands in appearance/ and variants/ (its
# config's code, e.g. MixConfig.l1_sigma, shapes the run too), both already listed.
TRAINING_MODULES = (
    "training/train.py",
    "networks",
    "losses",
    "config/variants",
    "geometry/warp.py",
    "geometry/camera.py",
    "data/pairs.py",
    "data/sequences.py",
)


def _training_files() -> list[Path]:
    """The source files of :data:`TRAINING_MODULES`, packages expanded to their sorted .py files."""
    return source_files(Path(__file__).resolve().parents[1], TRAINING_MODULES)


def _code_digest() -> str:
    """Hash of the source of :data:`TRAINING_MODULES` (each file under its path in the package)."""
    return source_digest(Path(__file__).resolve().parents[1], TRAINING_MODULES)


def fingerprint(
    params: Params,
    variant: str,
    num_pairs: int,
    seed: int,
    pretrained_sha256: str | None = None,
    data_sha256: str | None = None,
) -> str:
    """Hash of everything that shapes the training run, so a checkpoint is only resumed by its own
    run: parameters, seed, data size, the training code (:func:`_code_digest`) and, given
    ``data_sha256`` (:func:`msdepth.data.pairs.training_data_sha256`; :func:`train_variant` always
    gives it), the training data itself.

    With ``model.pretrained`` set, ``pretrained_sha256`` (its content's hash, required then) stands
    for its path: weights replaced under the same name train anew, moved ones still resume.
    """
    appearance = params.variant(variant)
    # Settings that change only speed do not invalidate a checkpoint, nor do the other seeds.
    ignored = ("seeds", *speed_only_train_keys())
    model = fingerprint_fields(params.model)
    if params.model.pretrained:  # unset, the field is left out: those fingerprints stay as they were
        if pretrained_sha256 is None:
            raise TrainingError("model.pretrained is set: the fingerprint needs its content's sha256")
        model["pretrained"] = f"sha256:{pretrained_sha256}"
    relevant = {
        "code": _code_digest(),
        "seed": seed,
        "data": [params.data.height, params.data.width, num_pairs],
        "model": model,
        "train": {k: v for k, v in fingerprint_fields(params.train).items() if k not in ignored},
        "loss": fingerprint_fields(params.loss),
        "appearance": appearance,
        appearance: asdict(params.appearance[appearance]),
    }
    if data_sha256 is not None:
        relevant["data_sha256"] = data_sha256
    return hashlib.sha256(json.dumps(relevant, sort_keys=True).encode()).hexdigest()[:16]


def _save_checkpoint(path: Path, state: dict) -> None:
    """``torch.save`` through a temp file and rename: never a truncated checkpoint.

    A failed write (disk full, quota) is a TrainingError; the previous checkpoint is untouched.
    """
    try:
        save_weights_file(path, state)
    except OSError as exc:
        raise TrainingError(
            f"{path}: cannot write the epoch {state.get('epoch')} checkpoint ({exc}); the previous "
            "checkpoint, if any, is intact and the run resumes from it"
        ) from exc


def _load_checkpoint(path: Path, device: torch.device) -> dict:
    """A checkpoint read weights-only (:func:`msdepth.networks.serialization.load_weights_file`); one that
    is corrupt or needs code is a TrainingError: refused, never silently trained over."""
    try:
        return load_weights_file(path, device, what="checkpoint", remedy="delete it to train this run anew")
    except MsdepthError as exc:
        raise TrainingError(str(exc)) from None


def _loader(
    dataset: StereoPairs, params: Params, seed: int, epoch: int, ctx: Context, pin_memory: bool = False
) -> DataLoader:
    # Shuffle order from (seed, epoch): a resumed epoch sees the same batches, on any world size.
    gen = torch.Generator().manual_seed(seed * 100_003 + epoch)
    dataset.set_epoch(epoch)
    return DataLoader(
        dataset,
        batch_size=params.train.batch_size,
        sampler=GlobalBatchSampler(len(dataset), params.train.batch_size, ctx, gen),
        num_workers=params.train.num_workers,
        generator=gen,
        persistent_workers=False,
        pin_memory=pin_memory,
    )


@dataclass
class _Run:
    """One training run once set up: what the resume, the epochs and the finish share."""

    params: Params
    variant: str
    seed: int
    ctx: Context
    device: torch.device
    dataset: StereoPairs | SequenceFrames
    model: DepthNetwork  # what is saved
    network: Callable[[torch.Tensor], list[torch.Tensor]]  # model, in DDP and/or compiled: what a step calls
    criterion: MonodepthLoss | MonocularLoss
    optimizer: torch.optim.Optimizer
    memory_format: torch.memory_format
    global_batch: int
    total_steps: int
    fingerprint: str
    # train.mode mono / mono_stereo: the pose network (in the checkpoint, not the model file) and
    # what a step calls (in DDP); None in stereo.
    pose_net: PoseNet | None = None
    pose_network: Callable[[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor]] | None = None
    loss_keys: tuple[str, ...] = LOSS_KEYS
    pretrained_sha256: str | None = None  # model.pretrained's content hash; None when unset
    pairing: dict = field(default_factory=dict)  # initial weights' and first batch's hashes
    # Progress: from the checkpoint when resumed, then advanced by every epoch.
    start_epoch: int = 0
    step: int = 0
    history: list[dict] = field(default_factory=list)
    seconds_before: float = 0.0  # training time of the runs that wrote the resumed checkpoint


def train_variant(
    params: Params,
    variant: str,
    pairs: list[tuple[Path, Path]],
    outputs: TrainOutputs,
    options: TrainOptions | None = None,
) -> TrainResult:
    """Train ``variant`` on ``pairs`` and write the final weights to ``outputs.model_path``.

    With ``train.mode`` mono or mono_stereo it trains Monodepth2's way on ``options.sequences``
    instead (``pairs`` unused; the pose network is kept in the checkpoint, the model file holds the
    depth network as in stereo). A checkpoint is written atomically at ``outputs.checkpoint_path``
    after every epoch and resumed from when its fingerprint matches. Under torchrun only rank 0
    writes files.

    Args:
        params: the run's params.
        variant: the loss variant to train.
        pairs: the stereo training pairs (in the order of ``options.cache``, where given).
        outputs: where the weights, checkpoint, dvclive curves, summary and timing go.
        options: the seed, pair cache, sequences, progress bar, per-epoch callback and pretrained
            hash (:class:`TrainOptions`); None: every default.

    Returns:
        The run's steps, epochs, timing and final losses.
    """
    opts = options if options is not None else TrainOptions()
    pretrained_sha256 = opts.pretrained_sha256
    if params.model.pretrained and pretrained_sha256 is None:
        pretrained_sha256 = file_sha256(params.model.pretrained, "weights")
    run_seed = params.train.seeds[0] if opts.seed is None else opts.seed
    run = _set_up(params, variant, pairs, run_seed, opts.cache, opts.sequences, pretrained_sha256)
    checkpoint_path = Path(outputs.checkpoint_path)
    _resume_or_start(run, checkpoint_path)
    live = _open_live(run, outputs.live_dir)
    started = time.perf_counter()
    resumed_from = run.start_epoch
    for epoch in range(run.start_epoch, params.train.epochs):
        means = _train_epoch(run, epoch, opts.progress)
        run.history.append({"epoch": epoch + 1, "step": run.step, **means})
        if live is not None:
            _log_epoch(live, run.history[-1], params.train, run.total_steps, run.loss_keys)
        if run.ctx.main:
            _save_epoch_checkpoint(
                run, checkpoint_path, epoch + 1, run.seconds_before + time.perf_counter() - started
            )
            log.info("%s epoch %d/%d: %s", variant, epoch + 1, params.train.epochs, json.dumps(means))
        if opts.on_epoch is not None:
            opts.on_epoch(epoch + 1, run.model, means)
    if live is not None:
        live.end()
    return _finish(run, outputs, resumed_from, time.perf_counter() - started)


def _set_up(
    params: Params,
    variant: str,
    pairs: list[tuple[Path, Path]],
    seed: int,
    cache: np.ndarray | None,
    sequences: Sequence[SequenceSample] | None = None,
    pretrained_sha256: str | None = None,
) -> _Run:
    """Seed, threads, process group, data, network, loss and optimiser of a run from scratch
    (without ``model.pretrained``'s weights: only a fresh start, not a resume, loads them)."""
    train_cfg = params.train
    torch.set_num_threads(train_cfg.threads)
    _seed_everything(seed)  # the same seed on every rank: identical initial weights
    ctx, device = distributed.setup(resolve_device(train_cfg.device), train_cfg.dist_timeout_s)
    configure_cudnn(train_cfg.cudnn_benchmark, device)
    dataset = _dataset(params, pairs, seed, cache, sequences)
    model = build_model(params).to(device)
    pairing = _pairing(model, dataset, params, seed, ctx)
    _refuse_bf16_cpu_hazard(params, model, device)
    memory_format = torch.channels_last if train_cfg.channels_last else torch.contiguous_format
    model = model.to(memory_format=memory_format)
    # DDP and the compiled wrapper share the parameters of `model`, which is what is saved.
    network = DistributedDataParallel(model) if ctx.world > 1 else model
    network = torch.compile(network) if train_cfg.compile else network
    mono = train_cfg.mode != "stereo"
    criterion = (build_monocular_loss if mono else build_loss)(params, variant).to(device)
    # After the loss: stereo's random draws are unchanged.
    pose_net = build_pose_net(params).to(device) if mono else None
    trainable = [*model.parameters(), *criterion.parameters(), *(pose_net.parameters() if pose_net else ())]
    optimizer = torch.optim.Adam(trainable, lr=train_cfg.learning_rate)
    global_batch = train_cfg.batch_size * ctx.world
    data_sha256 = _data_sha256(params, pairs, cache, sequences)
    steps_per_epoch = len(dataset) // global_batch if len(dataset) >= global_batch else 1
    _log_world(ctx, variant, train_cfg.batch_size)
    return _Run(
        params=params,
        variant=variant,
        seed=seed,
        ctx=ctx,
        device=device,
        dataset=dataset,
        model=model,
        network=network,
        criterion=criterion,
        optimizer=optimizer,
        memory_format=memory_format,
        global_batch=global_batch,
        total_steps=steps_per_epoch * train_cfg.epochs,
        fingerprint=fingerprint(params, variant, len(dataset), seed, pretrained_sha256, data_sha256),
        pose_net=pose_net,
        pose_network=DistributedDataParallel(pose_net) if pose_net and ctx.world > 1 else pose_net,
        loss_keys=MONO_LOSS_KEYS if mono else LOSS_KEYS,
        pretrained_sha256=pretrained_sha256,
        pairing=pairing,
    )


def _pairing(
    model: torch.nn.Module, dataset: StereoPairs | SequenceFrames, params: Params, seed: int, ctx: Context
) -> dict:
    """The run's pairing record (:func:`msdepth.training.pairing.pairing_record`): the initial
    weights and epoch 0's first batch, as the training loop will see it. Every random state is
    restored afterwards, so that recording it leaves the trained bytes as they were."""
    states = (torch.get_rng_state(), np.random.get_state(), random.getstate())
    try:
        first = next(iter(_loader(dataset, params, seed, 0, ctx)))
        return pairing_record(model, first)
    finally:
        torch.set_rng_state(states[0])
        np.random.set_state(states[1])
        random.setstate(states[2])


def _log_world(ctx: Context, variant: str, batch: int) -> None:
    """Under torchrun, the global batch the ranks make together (rank 0 says it)."""
    if ctx.world > 1 and ctx.main:
        log.info("%s: %d ranks x batch %d = global batch %d", variant, ctx.world, batch, batch * ctx.world)


def _refuse_bf16_cpu_hazard(params: Params, model: torch.nn.Module, device: torch.device) -> None:
    """A TrainingError, before any step, for bf16 on the CPU at an image size where a strided
    convolution sees a one-pixel-wide map (see :func:`one_pixel_wide_strided_convs`)."""
    if params.train.amp != "bf16" or device.type != "cpu":
        return
    height, width = params.data.height, params.data.width
    convs = one_pixel_wide_strided_convs(model, height, width)
    if convs:
        raise TrainingError(
            f"train.amp=bf16 on the CPU at data.height x data.width = {height}x{width}: the strided "
            f"convolution {convs[0]} sees a one-pixel-wide map, whose bf16 weight gradient PyTorch's CPU "
            "kernel returns as NaN at random; use a wider data.width or train.amp=none"
        )


def _dataset(
    params: Params,
    pairs: list[tuple[Path, Path]],
    seed: int,
    cache: np.ndarray | None,
    sequences: Sequence[SequenceSample] | None,
) -> StereoPairs | SequenceFrames:
    """The training samples of ``params.train.mode``: stereo pairs, or frame sequences."""
    t, h, w = params.train, params.data.height, params.data.width
    if t.mode == "stereo":
        return StereoPairs(pairs, h, w, augment=t.augment, seed=seed, cache=cache, crop_scale=t.crop_scale)
    if sequences is None:
        raise MsdepthError(f"train.mode {t.mode} trains on frame sequences, and none were given")
    stereo = t.mode == "mono_stereo"
    return SequenceFrames(sequences, t.source_frames, h, w, stereo=stereo, augment=t.augment, seed=seed)


def _data_sha256(
    params: Params,
    pairs: list[tuple[Path, Path]],
    cache: np.ndarray | None,
    sequences: Sequence[SequenceSample] | None,
) -> str:
    """:func:`training_data_sha256` of what ``params.train.mode`` trains on: the pair cache (or
    the pairs' files), or every frame of the sequences."""
    if params.train.mode == "stereo":
        return training_data_sha256(cache, [] if cache is not None else [p for pair in pairs for p in pair])
    files = [
        path
        for s in sequences or ()
        for path in (s.target, *(s.sources[k] for k in sorted(s.sources)), *([s.stereo] if s.stereo else []))
    ]
    return training_data_sha256(None, files)


def _resume_or_start(run: _Run, checkpoint_path: Path) -> None:
    """Resume ``run`` from its checkpoint, or start it fresh: only then are ``model.pretrained``'s
    weights loaded. A resumed run has them in its checkpoint and never reads the file (which may
    have moved since)."""
    if not _resume(run, checkpoint_path) and run.params.model.pretrained:
        pretrained = run.params.model.pretrained
        _load_pretrained_encoders(pretrained, run.model, run.pose_net, run.pretrained_sha256)


def _resume(run: _Run, checkpoint_path: Path) -> bool:
    """Continue ``run`` from the checkpoint at ``checkpoint_path`` if it is this run's (same
    fingerprint); returns whether it did."""
    if not checkpoint_path.exists():
        return False
    state = _load_checkpoint(checkpoint_path, run.device)
    if state.get("fingerprint") != run.fingerprint:
        log.info("ignoring checkpoint %s: it belongs to other parameters or training code", checkpoint_path)
        return False
    _restore(run, state, checkpoint_path)
    log.info("resuming %s from epoch %d (step %d)", run.variant, run.start_epoch, run.step)
    return True


CHECKPOINT_KEYS = ("epoch", "step", "history", "model", "criterion", "optimizer", "torch_rng")


def _restore(run: _Run, state: dict, path: Path) -> None:
    """Load a checkpoint's ``state`` into ``run``; a TrainingError naming ``path`` and what is wrong
    when it is malformed (a missing entry, wrong shapes, a bad RNG state, progress out of range)."""

    def malformed(problem: str) -> TrainingError:
        return TrainingError(f"{path}: a malformed checkpoint ({problem}); delete it to train this run anew")

    missing = [k for k in (*CHECKPOINT_KEYS, *(("pose",) if run.pose_net else ())) if k not in state]
    if missing:
        raise malformed(f"no {', '.join(missing)} entry")
    epoch, step, history = state["epoch"], state["step"], state["history"]
    counts = all(isinstance(v, int) and not isinstance(v, bool) for v in (epoch, step))
    if not counts or not 0 <= epoch <= run.params.train.epochs or step < 0:
        raise malformed(f"epoch {repr(epoch)[:20]} and step {repr(step)[:20]} are not counts of this run")
    if not isinstance(history, list) or len(history) != epoch:
        raise malformed(
            f"a history of {len(history) if isinstance(history, list) else 'no'} epochs at epoch {epoch}"
        )
    seconds = state.get("seconds", 0.0)
    if not isinstance(seconds, (int, float)) or not math.isfinite(seconds) or seconds < 0:
        raise malformed(f"seconds {repr(seconds)[:20]}")
    try:
        run.model.load_state_dict(state["model"])
        run.criterion.load_state_dict(state["criterion"])
        run.optimizer.load_state_dict(state["optimizer"])
        if run.pose_net is not None:
            run.pose_net.load_state_dict(state["pose"])
        torch.set_rng_state(state["torch_rng"])
    except (RuntimeError, KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        # load_state_dict's first line is only "Error(s) in loading ...:"; what is wrong follows it
        raise malformed(" ".join(str(exc).split())[:200] or type(exc).__name__) from None
    run.start_epoch, run.step, run.history, run.seconds_before = epoch, step, history, float(seconds)


def _open_live(run: _Run, live_dir: str | os.PathLike | None):
    """The dvclive logger of ``live_dir`` (rank 0 only; else None), the resumed epochs replayed."""
    if live_dir is None or not run.ctx.main:
        return None
    from dvclive import Live

    # Always a fresh log, the epochs of a resumed checkpoint replayed from its history: DVC
    # deletes a stage's outputs (these curves) before it reruns it, and the curves must not
    # depend on whether, or where, the run was interrupted.
    live = Live(str(live_dir), resume=False, save_dvc_exp=False, dvcyaml=False)
    live.step = 0
    for entry in run.history:
        _log_epoch(live, entry, run.params.train, run.total_steps, run.loss_keys)
    return live


def _train_epoch(run: _Run, epoch: int, progress: bool) -> dict[str, float]:
    """One epoch (0-based) of optimiser steps; returns its mean losses, averaged over ranks."""
    train_cfg, dataset = run.params.train, run.dataset
    run.model.train()
    sums = dict.fromkeys(run.loss_keys, 0.0)
    batches = 0
    unread: list[tuple[int, torch.Tensor, torch.Tensor]] = []  # (step, batch indices, loss values)
    sync_every = host_sync_interval(train_cfg.sync_every, run.device)
    bar = tqdm(
        _loader(dataset, run.params, run.seed, epoch, run.ctx, pin_memory=run.device.type == "cuda"),
        desc=f"{run.variant} epoch {epoch + 1}/{train_cfg.epochs}",
        disable=not progress or not run.ctx.main,
        leave=False,
    )
    for batch in bar:
        for group in run.optimizer.param_groups:
            group["lr"] = learning_rate(
                train_cfg.learning_rate, run.step, run.total_steps, train_cfg.schedule
            )
        losses = _batch_losses(run, batch)
        unread.append((run.step, batch["index"], torch.stack([losses[k].detach() for k in run.loss_keys])))
        if len(unread) >= sync_every:  # before this step's update: with 1, a NaN never reaches the weights
            batches += _read_losses(unread, sums, dataset, run.variant, epoch)
            bar.set_postfix(loss=f"{sums['total'] / batches:.4f}")
        run.optimizer.zero_grad(set_to_none=True)
        losses["total"].backward()
        distributed.average_gradients(run.criterion, run.ctx)  # learned level weights stay identical
        run.optimizer.step()
        run.step += 1
    batches += _read_losses(unread, sums, dataset, run.variant, epoch)
    return distributed.mean_over_ranks({k: v / max(batches, 1) for k, v in sums.items()}, run.ctx)


def _save_epoch_checkpoint(run: _Run, path: Path, epoch: int, seconds: float) -> None:
    """The resume state after ``epoch`` (1-based) epochs, ``seconds`` of training in all."""
    state = {
        "fingerprint": run.fingerprint,
        "epoch": epoch,
        "step": run.step,
        "history": run.history,
        "model": run.model.state_dict(),
        "criterion": run.criterion.state_dict(),
        "optimizer": run.optimizer.state_dict(),
        "torch_rng": torch.get_rng_state(),
        "seconds": seconds,
    }
    if run.pose_net is not None:
        state["pose"] = run.pose_net.state_dict()
    _save_checkpoint(path, state)


def _finish(run: _Run, outputs: TrainOutputs, resumed_from: int, this_run: float) -> TrainResult:
    """Check the replicas agree, save the model, leave the process group, write the summary files."""
    seconds = run.seconds_before + this_run
    distributed.check_replicas([run.model, run.criterion, *([run.pose_net] if run.pose_net else [])], run.ctx)
    if run.ctx.main:
        save_model(outputs.model_path, run.model, run.criterion, run.params, run.variant, run.seed)
    run.network = run.model  # drop the DDP wrapper: it holds the process group, which teardown() frees
    run.pose_network = run.pose_net
    distributed.teardown()
    final = run.history[-1] if run.history else {}
    result = TrainResult(
        steps=run.step,
        epochs=run.params.train.epochs,
        resumed_from_epoch=resumed_from,
        seconds=seconds,
        seconds_this_run=this_run,
        examples_per_second=run.step * run.global_batch / seconds if seconds > 0 and run.step else math.nan,
        final_losses={k: final.get(k, math.nan) for k in run.loss_keys},
    )
    if run.ctx.main:
        record = asdict(result)
        timing = {k: record.pop(k) for k in TIMING_KEYS}
        record["pairing"] = run.pairing
        if outputs.summary_path is not None:
            write_json(outputs.summary_path, record)
        if outputs.timing_path is not None:
            write_json(outputs.timing_path, timing)
    return result


def configure_cudnn(benchmark: bool, device: torch.device) -> None:
    """On CUDA, let cuDNN time its convolution algorithms (``train.cudnn_benchmark``); elsewhere
    leave the process-wide flag alone."""
    if device.type == "cuda":
        torch.backends.cudnn.benchmark = benchmark


def host_sync_interval(sync_every: int, device: torch.device) -> int:
    """Steps between host reads of the loss: ``sync_every``, or with 0 every step on the CPU
    (where a read costs nothing) and every 50 on a GPU. Each read waits for the GPU's queue to
    drain, after which the GPU idles while Python queues the next step's ~1,500 kernels."""
    if sync_every > 0:
        return sync_every
    return 1 if device.type == "cpu" else 50


def _read_losses(
    unread: list[tuple[int, torch.Tensor, torch.Tensor]],
    sums: dict[str, float],
    dataset: StereoPairs | SequenceFrames,
    variant: str,
    epoch: int,
) -> int:
    """Add the losses of the ``unread`` steps to ``sums`` in step order (one host read) and empty
    the list; returns how many steps that was. A non-finite total is a TrainingError naming the
    first such step and its batch's files."""
    if not unread:
        return 0
    rows = torch.stack([values for _, _, values in unread]).cpu().tolist()
    for (step, index, _), row in zip(unread, rows, strict=True):
        if not math.isfinite(row[0]):
            names = [dataset.name(int(i)) for i in index]
            raise TrainingError(
                f"{variant}: non-finite loss {row[0]} at step {step} (epoch {epoch + 1}); batch: {names}. "
                "No checkpoint was written for this epoch."
            )
        for k, value in zip(sums, row, strict=True):  # sums: the run's loss keys, in their order
            sums[k] += value
    count = len(unread)
    unread.clear()
    return count


def _batch_losses(run: _Run, batch: dict) -> dict[str, torch.Tensor]:
    """The loss terms of one batch: Monodepth's stereo loss, or with a pose network Monodepth2's."""
    amp, device = run.params.train.amp, run.device
    if run.pose_network is None:
        left = batch["left"].to(device, non_blocking=True)
        right = batch["right"].to(device, non_blocking=True)
        scale = run.params.train.crop_scale
        return forward_and_loss(run.network, run.criterion, left, right, amp, run.memory_format, scale)

    def depth(image: torch.Tensor) -> list[torch.Tensor]:
        # The left-view channel of every scale as Monodepth2's sigmoid disparity in [0, 1].
        with torch.autocast(image.device.type, dtype=torch.bfloat16, enabled=amp == "bf16"):
            disps = run.network(image.contiguous(memory_format=run.memory_format))
        return [d[:, :1].float() / MAX_DISPARITY for d in disps]

    target = batch["target"].to(device, non_blocking=True)
    sources = batch["sources"].to(device, non_blocking=True)
    neighbours = {o: sources[:, j] for j, o in enumerate(run.params.train.source_frames)}
    partner = batch["partner"].to(device, non_blocking=True) if "partner" in batch else None
    k = batch["k"].to(device, non_blocking=True)
    return monocular_losses(
        depth, run.pose_network, run.criterion, target, neighbours, k, partner, batch["right"]
    )


def forward_and_loss(
    network: Callable[[torch.Tensor], list[torch.Tensor]],
    criterion: MonodepthLoss,
    left: torch.Tensor,
    right: torch.Tensor,
    amp: str = "none",
    memory_format: torch.memory_format = torch.contiguous_format,
    crop_scale: int = 1,
) -> dict[str, torch.Tensor]:
    """The network on ``left`` (bf16 autocast with ``amp == "bf16"``, in ``memory_format``) and the
    loss of its disparities, always in fp32: SSIM's E[x²] - E[x]² cancels badly in bf16.

    The network's disparity is a fraction of the width of the image it infers on; on crops of
    1/``crop_scale`` of that width (``train.crop_scale``) the loss warps the crop by that many
    times the fraction, the same shift in pixels."""
    with torch.autocast(left.device.type, dtype=torch.bfloat16, enabled=amp == "bf16"):
        disps = network(left.contiguous(memory_format=memory_format))
    disps = [d.float() for d in disps]
    return criterion([d * crop_scale for d in disps] if crop_scale != 1 else disps, left, right)


def _log_epoch(
    live, entry: dict, train_cfg: TrainConfig, total_steps: int, keys: tuple[str, ...] = LOSS_KEYS
) -> None:
    """One epoch's mean losses (a ``history`` entry, ``keys``) and the learning rate of its last
    step to dvclive."""
    for k in keys:
        live.log_metric(f"train/{k}", entry[k])
    lr = learning_rate(train_cfg.learning_rate, entry["step"] - 1, total_steps, train_cfg.schedule)
    live.log_metric("train/learning_rate", lr)
    live.next_step()
