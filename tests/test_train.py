"""Training: resume after an interruption, non-finite losses, the GPU speed switches (run on CPU)."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

import msdepth.training.train as train_mod
from msdepth.config.params import Params, params_from_dict
from msdepth.networks.vgg import MonodepthVGG
from msdepth.training.train import (
    TrainingError,
    TrainOptions,
    TrainOutputs,
    learning_rate,
    load_model,
    train_variant,
)

H, W = 32, 64


def _params(weights: str = "wang", **train) -> Params:
    return params_from_dict(
        {
            "data": {"height": H, "width": W},
            "model": {"width_multiplier": 0.0625},
            "train": {"epochs": 2, "batch_size": 4, "threads": 1, **train},
            "msssim": {"levels": 3, "weights": weights},
        }
    )


def _weights(path: Path) -> dict[str, torch.Tensor]:
    return load_model(path)[0].state_dict()


def _train(params: Params, pairs, tmp: Path, variant: str = "ssim"):
    outputs = TrainOutputs(tmp / "model.pt", tmp / "ck.pt", live_dir=tmp / "live")
    return train_variant(params, variant, pairs, outputs, TrainOptions(progress=False))


def _curves(live: Path) -> dict[str, list]:
    """dvclive's per-epoch TSVs without their wall-clock column."""
    import pandas as pd

    tsvs = sorted((live / "plots" / "metrics" / "train").glob("*.tsv"))
    return {
        p.name: pd.read_csv(p, sep="\t").drop(columns="timestamp", errors="ignore").values.tolist()
        for p in tsvs
    }


@pytest.mark.parametrize("variant", ["ssim", "msssim"])
def test_interrupted_run_resumes_to_the_same_weights(
    pairs, tmp_path: Path, monkeypatch, variant: str
) -> None:
    params = _params()
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    full = _train(params, pairs, tmp_path / "a", variant)

    real_save = train_mod._save_checkpoint

    def save_then_die(path, state):
        real_save(path, state)
        raise KeyboardInterrupt  # killed right after the first epoch's checkpoint

    monkeypatch.setattr(train_mod, "_save_checkpoint", save_then_die)
    with pytest.raises(KeyboardInterrupt):
        _train(params, pairs, tmp_path / "b", variant)
    assert not (tmp_path / "b" / "model.pt").exists()
    shutil.rmtree(tmp_path / "b" / "live")  # DVC deletes a stage's outputs before it reruns it
    monkeypatch.setattr(train_mod, "_save_checkpoint", real_save)
    resumed = _train(params, pairs, tmp_path / "b", variant)

    assert resumed.resumed_from_epoch == 1 and full.resumed_from_epoch == 0
    assert resumed.steps == full.steps == 4
    a, b = _weights(tmp_path / "a" / "model.pt"), _weights(tmp_path / "b" / "model.pt")
    for name in a:
        assert torch.equal(a[name], b[name]), name
    # The curves hold every epoch, the ones before the interruption replayed from the checkpoint.
    curves = _curves(tmp_path / "a" / "live")
    assert len(curves["total.tsv"]) == 2 and _curves(tmp_path / "b" / "live") == curves
    # A rerun that finds the finished checkpoint trains nothing and still writes the whole run.
    shutil.rmtree(tmp_path / "a" / "live")
    again = _train(params, pairs, tmp_path / "a", variant)
    assert again.resumed_from_epoch == 2 and again.seconds_this_run < again.seconds
    assert 0 < again.seconds - again.seconds_this_run <= full.seconds  # the first run's time, as checkpointed
    assert again.final_losses == full.final_losses
    assert _curves(tmp_path / "a" / "live") == curves


def test_checkpoint_of_other_params_is_not_resumed(pairs, tmp_path: Path) -> None:
    _train(_params(epochs=1), pairs, tmp_path)
    other = _train(_params(epochs=1, learning_rate=5e-4), pairs, tmp_path)
    assert other.resumed_from_epoch == 0


def test_checkpoint_of_other_training_code_is_not_resumed(pairs, tmp_path: Path, monkeypatch) -> None:
    """A code change that makes DVC rerun the stage trains anew (the model then matches the code)."""
    _train(_params(epochs=1), pairs, tmp_path)
    assert _train(_params(epochs=1), pairs, tmp_path).resumed_from_epoch == 1  # same code: resumed
    monkeypatch.setattr(train_mod, "_code_digest", lambda: "edited losses.py")
    assert _train(_params(epochs=1), pairs, tmp_path).resumed_from_epoch == 0


def test_checkpoint_of_other_training_data_is_not_resumed(pairs, tmp_path: Path) -> None:
    """Re-rendered images of the same count and size (e.g. data.synthetic.train_cars) train anew:
    the fingerprint holds the pair cache's pixels, or each uncached file's size and time."""
    from msdepth.data.pairs import build_pair_cache, load_pair_cache

    params = _params(epochs=1)
    build_pair_cache(pairs, H, W, tmp_path / "cache.npy", progress=False)
    cache = np.array(load_pair_cache(tmp_path / "cache.npy", len(pairs), H, W))

    def run(images: np.ndarray | None) -> int:
        outputs = TrainOutputs(tmp_path / "model.pt", tmp_path / "ck.pt")
        return train_variant(params, "ssim", pairs, outputs, TrainOptions(progress=False, cache=images))

    assert run(cache).resumed_from_epoch == 0
    assert run(cache.copy()).resumed_from_epoch == 1  # the same pixels: resumed
    changed = cache.copy()
    changed[5, 1, 3, 7, 0] ^= 1  # one bit of one pixel of one right view
    assert run(changed).resumed_from_epoch == 0
    assert run(None).resumed_from_epoch == 0  # decoded per sample: the files stand for the data
    assert run(None).resumed_from_epoch == 1
    copy = tmp_path / "l3.png"  # the same bytes in another file: trained anew, never a wrong resume
    shutil.copy(pairs[3][0], copy)
    moved = [*pairs[:3], (copy, pairs[3][1]), *pairs[4:]]
    outputs = TrainOutputs(tmp_path / "model.pt", tmp_path / "ck.pt")
    assert train_variant(params, "ssim", moved, outputs, TrainOptions(progress=False)).resumed_from_epoch == 0


def test_code_digest_covers_the_train_stage_source_deps(tmp_path: Path, monkeypatch) -> None:
    from msdepth.pipeline.fingerprints import import_closure

    root = Path(__file__).resolve().parents[1]
    closure = {
        p.relative_to(root / "src" / "msdepth").as_posix()
        for p in import_closure(root / "stages" / "train.py", root / "src")
    }
    # The stage's fingerprint covers its whole import closure (tests/test_dvc_deps.py); the digest
    # covers the part that shapes a run, so every digested file must be in it (a change reruns DVC).
    package, real = Path(train_mod.__file__).resolve().parents[1], train_mod._code_digest()
    names = [p.relative_to(package).as_posix() for p in train_mod._training_files()]
    assert set(names) <= closure
    # Every listed file's bytes count (every .py file of a listed package).
    expected = {"losses/appearance/__init__.py", "losses/appearance/msssim.py", "config/variants/mix.py"}
    assert expected <= set(names)
    fake = tmp_path / "msdepth"
    for name in names:
        (fake / name).parent.mkdir(parents=True, exist_ok=True)
        (fake / name).write_bytes((package / name).read_bytes())
    monkeypatch.setattr(train_mod, "__file__", str(fake / "training" / "train.py"))
    before = train_mod._code_digest()
    assert before == real  # the same bytes elsewhere: the same digest
    for name in names:
        original = (fake / name).read_bytes()
        (fake / name).write_bytes(original + b"# edited\n")
        assert train_mod._code_digest() != before, name
        (fake / name).write_bytes(original)
    assert train_mod._code_digest() == before


@pytest.mark.parametrize("sync_every", [0, 3])
def test_non_finite_loss_stops_with_step_and_files(
    pairs, tmp_path: Path, monkeypatch, sync_every: int
) -> None:
    """Read every step (0 = automatic, every step on the CPU) or, as on a GPU, a few steps late
    (3: here at the end of the 2-step epoch, after a NaN update): the error names the first bad step."""
    real_forward = train_mod.MonodepthLoss.forward
    calls = {"n": 0}

    def poisoned(self, disps, left, right):
        calls["n"] += 1
        out = real_forward(self, disps, left, right)
        if calls["n"] == 3:  # step 2, in the second epoch
            out = dict(out, total=out["total"] * float("nan"))
        return out

    monkeypatch.setattr(train_mod.MonodepthLoss, "forward", poisoned)
    with pytest.raises(TrainingError, match=r"non-finite loss nan at step 2 \(epoch 2\); batch: \[.*\.png"):
        _train(_params(sync_every=sync_every), pairs, tmp_path)
    state = torch.load(tmp_path / "ck.pt", weights_only=True)
    assert state["epoch"] == 1  # the last checkpoint is the good first epoch
    assert all(torch.isfinite(v).all() for v in state["model"].values())
    assert not (tmp_path / "model.pt").exists()


def test_reading_the_loss_every_few_steps_changes_nothing(pairs, tmp_path: Path) -> None:
    """The loss read from the host every step or every 3 (a partial group at each epoch's end):
    the same weights and the same logged epoch means, bit for bit."""
    for name, sync_every in (("every", 1), ("grouped", 3)):
        (tmp_path / name).mkdir()
        _train(_params(sync_every=sync_every, epochs=3, batch_size=2), pairs, tmp_path / name)
    a, b = _weights(tmp_path / "every" / "model.pt"), _weights(tmp_path / "grouped" / "model.pt")
    assert all(torch.equal(a[k], b[k]) for k in a)
    history = [torch.load(tmp_path / n / "ck.pt", weights_only=True)["history"] for n in ("every", "grouped")]
    assert history[0] == history[1] and len(history[0]) == 3
    assert _curves(tmp_path / "every" / "live") == _curves(tmp_path / "grouped" / "live")


def test_cudnn_benchmark_is_set_for_cuda_only(monkeypatch) -> None:
    monkeypatch.setattr(torch.backends.cudnn, "benchmark", False)
    train_mod.configure_cudnn(True, torch.device("cpu"))
    assert torch.backends.cudnn.benchmark is False
    train_mod.configure_cudnn(True, torch.device("cuda"))
    assert torch.backends.cudnn.benchmark is True
    train_mod.configure_cudnn(False, torch.device("cuda"))
    assert torch.backends.cudnn.benchmark is False


def test_host_sync_interval() -> None:
    assert train_mod.host_sync_interval(0, torch.device("cpu")) == 1
    assert train_mod.host_sync_interval(0, torch.device("cuda")) == 50
    assert train_mod.host_sync_interval(7, torch.device("cpu")) == 7


def _bf16_params(**train) -> Params:
    # 32 x 96: the encoder's last strided convolution sees a 2-px-wide map (at 64 wide, 1 px: refused).
    params = _params(**train)
    return dataclasses.replace(params, data=dataclasses.replace(params.data, width=96))


def test_bf16_autocast_and_channels_last_train_on_cpu(pairs, tmp_path: Path) -> None:
    (tmp_path / "fp32").mkdir()
    (tmp_path / "bf16").mkdir()
    _train(_bf16_params(), pairs, tmp_path / "fp32")
    result = _train(_bf16_params(amp="bf16", channels_last=True), pairs, tmp_path / "bf16")
    assert all(np.isfinite(v) for v in result.final_losses.values())
    a, b = _weights(tmp_path / "fp32" / "model.pt"), _weights(tmp_path / "bf16" / "model.pt")
    assert any(not torch.equal(a[k], b[k]) for k in a)  # autocast really changed the arithmetic
    # ... but only by bf16 rounding: the runs stay close.
    diffs = [float((a[k] - b[k]).abs().max()) for k in a]
    assert max(diffs) < 0.05


def test_bf16_on_the_cpu_refuses_a_one_pixel_wide_strided_convolution(pairs, tmp_path: Path) -> None:
    """At 32 x 64 the encoder's last stride-2 convolution sees a 1-px-wide map, whose bf16 weight
    gradient PyTorch's CPU kernel returns as NaN at random: refused before any step, naming it."""
    from msdepth.networks.device import one_pixel_wide_strided_convs

    model = train_mod.build_model(_params())
    assert one_pixel_wide_strided_convs(model, H, W) == ["encoder.6.0.0"]
    assert one_pixel_wide_strided_convs(model, H, 96) == []
    assert model.training  # the probe put the model back in training mode
    with pytest.raises(TrainingError, match=r"train.amp=bf16 on the CPU at .* 32x64: .* encoder.6.0.0 sees"):
        _train(_params(amp="bf16"), pairs, tmp_path)
    assert not (tmp_path / "ck.pt").exists() and not (tmp_path / "model.pt").exists()
    _train(_params(), pairs, tmp_path)  # fp32 at the same size is fine


def test_speed_switches_keep_the_checkpoint_fingerprint() -> None:
    base = _params()
    fast = dataclasses.replace(
        base,
        train=dataclasses.replace(
            base.train, channels_last=True, compile=True, num_workers=2, sync_every=50, cudnn_benchmark=False
        ),
    )
    assert train_mod.fingerprint(base, "ssim", 8, 0) == train_mod.fingerprint(fast, "ssim", 8, 0)
    amp = dataclasses.replace(base, train=dataclasses.replace(base.train, amp="bf16"))
    assert train_mod.fingerprint(base, "ssim", 8, 0) != train_mod.fingerprint(amp, "ssim", 8, 0)
    # A run's checkpoint is its seed's alone, and adding seeds to train.seeds does not void it.
    assert train_mod.fingerprint(base, "ssim", 8, 0) != train_mod.fingerprint(base, "ssim", 8, 1)
    more = dataclasses.replace(base, train=dataclasses.replace(base.train, seeds=(0, 1, 2)))
    assert train_mod.fingerprint(base, "ssim", 8, 0) == train_mod.fingerprint(more, "ssim", 8, 0)


def test_unknown_amp_mode_is_a_config_error() -> None:
    from msdepth.errors import ConfigError

    with pytest.raises(ConfigError, match="train.amp"):
        _params(amp="fp16")


def test_compile_switch_compiles_the_network_and_saves_its_weights(
    pairs, tmp_path: Path, monkeypatch
) -> None:
    # A real torch.compile takes ~1 min on CPU (measured), so the wiring is tested with a stand-in.
    compiled = []

    def fake_compile(model):
        compiled.append(model)
        return lambda x: model(x)

    monkeypatch.setattr(torch, "compile", fake_compile)
    _train(_params(epochs=1, compile=True), pairs, tmp_path)
    assert len(compiled) == 1 and isinstance(compiled[0], MonodepthVGG)
    saved = _weights(tmp_path / "model.pt")
    for name, value in compiled[0].state_dict().items():
        assert torch.equal(saved[name], value)


def test_disk_full_while_checkpointing_keeps_the_previous_checkpoint(
    pairs, tmp_path: Path, monkeypatch
) -> None:
    real_save = torch.save
    saves = {"n": 0}

    def save_until_full(obj, f, *args, **kwargs):
        saves["n"] += 1
        if saves["n"] == 2:  # the second epoch's checkpoint: half written, then ENOSPC
            f.write(b"PK\x03\x04 partial")
            raise OSError(28, "No space left on device")
        return real_save(obj, f, *args, **kwargs)

    monkeypatch.setattr(torch, "save", save_until_full)
    with pytest.raises(TrainingError, match=r"ck.pt: cannot write the epoch 2 checkpoint .*No space left"):
        _train(_params(), pairs, tmp_path)
    state = torch.load(tmp_path / "ck.pt", weights_only=True)
    assert state["epoch"] == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ck.pt", "live"]  # no temp file, no model
    monkeypatch.setattr(torch, "save", real_save)
    assert _train(_params(), pairs, tmp_path).resumed_from_epoch == 1


def test_each_seed_is_its_own_repeatable_run(pairs, tmp_path: Path) -> None:
    params = _params(seeds=[0, 1])
    for name, seed in (("a", 1), ("b", 1), ("c", 0)):
        (tmp_path / name).mkdir()
        train_variant(
            params,
            "ssim",
            pairs,
            TrainOutputs(
                tmp_path / name / "model.pt",
                tmp_path / name / "ck.pt",
                summary_path=tmp_path / name / "summary.json",
                timing_path=tmp_path / name / "timing.json",
            ),
            TrainOptions(progress=False, seed=seed),
        )
    a, b, c = (_weights(tmp_path / n / "model.pt") for n in "abc")
    assert all(torch.equal(a[k], b[k]) for k in a)  # the same seed: bit-identical on CPU ...
    # ... and so are the files, whatever temp names they were written through (DVC hashes them).
    assert (tmp_path / "a" / "model.pt").read_bytes() == (tmp_path / "b" / "model.pt").read_bytes()
    assert any(not torch.equal(a[k], c[k]) for k in a)  # another seed: another run
    assert load_model(tmp_path / "a" / "model.pt")[1]["seed"] == 1
    summary = json.loads((tmp_path / "a" / "summary.json").read_text())
    assert summary["steps"] == 2 * (len(pairs) // 4) and "seconds" not in summary
    # The tracked summary of a rerun is byte-identical; what varies (time) is in the timing file.
    assert (tmp_path / "a" / "summary.json").read_bytes() == (tmp_path / "b" / "summary.json").read_bytes()
    timing = json.loads((tmp_path / "a" / "timing.json").read_text())
    assert timing["resumed_from_epoch"] == 0 and timing["seconds"] > 0


def test_speed_only_keys_are_marked_once_and_leave_the_fingerprint_alone():
    from msdepth.config.params import speed_only_train_keys
    from msdepth.training.train import fingerprint

    keys = set(speed_only_train_keys())
    assert keys == {
        "num_workers",
        "device",
        "threads",
        "channels_last",
        "compile",
        "cudnn_benchmark",
        "sync_every",
        "launcher",
        "dist_timeout_s",
    }
    base = _params()
    for key, value in {"threads": 2, "sync_every": 3, "channels_last": True, "dist_timeout_s": 5.0}.items():
        changed = _params(**{key: value})
        assert fingerprint(changed, "ssim", 8, 0) == fingerprint(base, "ssim", 8, 0), key
    for key, value in {
        "learning_rate": 2e-4,
        "amp": "bf16",
        "nproc": 2,
        "epochs": 3,
        "schedule": "cosine",
    }.items():
        changed = _params(**{key: value})
        assert fingerprint(changed, "ssim", 8, 0) != fingerprint(base, "ssim", 8, 0), key


# fingerprint(params_from_dict(raw), variant, 8, 0) with code_digest() fixed to "fixed", computed
# at bdd8107 (before the appearance registry and loss.kernels): the parameter part of the
# fingerprint of every existing variant is unchanged, so only a code change voids a checkpoint.
# The learning rate is given: it was the default then (1e-4; 3e-4 since issue 52's screen).
_THEN = {"learning_rate": 1.0e-4}
PREVIOUS_FINGERPRINTS = [
    ({"train": _THEN}, "ssim", "e02d73895de98460"),
    ({"train": _THEN}, "msssim", "88432aecc7937444"),
    ({"msssim": {"kernel_size": 7, "weights": "learned"}, "train": _THEN}, "msssim", "e3c7ae91561bcadf"),
    ({"ssim": {"padding": "reflect"}, "train": {"amp": "bf16", **_THEN}}, "ssim", "2f6177ff73ee846a"),
    ({"ssim": {"padding": "reflect"}, "train": {"amp": "bf16", **_THEN}}, "msssim", "2b6d2b03930d7459"),
]


@pytest.mark.parametrize(("raw", "variant", "expected"), PREVIOUS_FINGERPRINTS)
def test_fingerprint_of_existing_variants_is_unchanged(monkeypatch, raw, variant, expected) -> None:
    monkeypatch.setattr(train_mod, "_code_digest", lambda: "fixed")
    params = params_from_dict(raw)
    assert train_mod.fingerprint(params, variant, 8, 0) == expected
    # The kernels switch counts once it leaves its default (it changes the rounding).
    reference = params_from_dict({**raw, "loss": {"kernels": "reference"}})
    assert train_mod.fingerprint(reference, variant, 8, 0) != expected


def test_cosine_schedule_warms_up_then_decays_to_zero_and_step_keeps_monodepths() -> None:
    total = 1000
    cosine = [learning_rate(3e-4, s, total, "cosine") for s in range(total)]
    peak = cosine.index(max(cosine))
    assert peak == 49 and cosine[peak] == pytest.approx(3e-4)  # 5 % warm-up: steps 0..49
    assert all(a < b for a, b in zip(cosine[:peak], cosine[1 : peak + 1], strict=True))
    assert all(a >= b for a, b in zip(cosine[peak:-1], cosine[peak + 1 :], strict=True))
    assert cosine[-1] == pytest.approx(0.0, abs=1e-12)
    step = [learning_rate(3e-4, s, total) for s in (0, 599, 600, 799, 800, 999)]
    assert step == [3e-4, 3e-4, 1.5e-4, 1.5e-4, 7.5e-5, 7.5e-5]
    with pytest.raises(ValueError, match="unknown schedule 'linear'"):
        learning_rate(3e-4, 0, total, "linear")


def test_the_run_follows_its_schedule(pairs, tmp_path: Path, monkeypatch) -> None:
    """train_variant sets each step's learning rate from train.schedule."""
    seen: list[float] = []
    real_step = torch.optim.Adam.step

    def spy(self, *args, **kwargs):
        seen.append(self.param_groups[0]["lr"])
        return real_step(self, *args, **kwargs)

    monkeypatch.setattr(torch.optim.Adam, "step", spy)
    _train(_params(epochs=2, schedule="cosine", learning_rate=1e-3), pairs, tmp_path)
    assert seen == [learning_rate(1e-3, s, len(seen), "cosine") for s in range(len(seen))]
    assert len(seen) >= 4 and max(seen) == pytest.approx(1e-3)


def test_crop_training_warps_by_the_crop_scale_and_infers_on_the_whole_image(pairs, tmp_path: Path) -> None:
    """train.crop_scale 2: the loss of a crop sees the network's disparity (a fraction of the whole
    image's width) times 2, the same pixel shift in the half-width crop, and the model file says the
    network infers at twice the crop's size."""
    from msdepth.training.train import build_loss, build_model, forward_and_loss

    params = _params(crop_scale=2)
    assert params.image_size == (2 * H, 2 * W)
    torch.manual_seed(0)
    net, criterion = build_model(params), build_loss(params, "ssim")
    left, right = torch.rand(2, 3, H, W), torch.rand(2, 3, H, W)
    cropped = forward_and_loss(net, criterion, left, right, crop_scale=2)
    doubled = forward_and_loss(lambda x: [2 * d for d in net(x)], criterion, left, right)
    plain = forward_and_loss(net, criterion, left, right)
    for key, value in cropped.items():
        assert torch.equal(value, doubled[key])
    assert not torch.equal(cropped["total"], plain["total"])
    _train(dataclasses.replace(params, train=dataclasses.replace(params.train, epochs=1)), pairs, tmp_path)
    state = torch.load(tmp_path / "model.pt", weights_only=True)
    assert (state["height"], state["width"]) == (2 * H, 2 * W)


def test_crop_scale_is_refused_where_it_does_not_apply() -> None:
    from msdepth.config.params import ConfigError

    with pytest.raises(ConfigError, match="train.crop_scale"):
        params_from_dict(
            {"train": {"crop_scale": 2, "mode": "mono"}, "data": {"synthetic": {"sequence_length": 3}}}
        )
    with pytest.raises(ConfigError, match="train.crop_scale"):
        params_from_dict({"train": {"crop_scale": 5}})
    with pytest.raises(ConfigError, match="train.crop_scale"):
        params_from_dict({"data": {"height": 2048, "width": 4096}, "train": {"crop_scale": 2}})
