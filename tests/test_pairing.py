"""The losses' runs are paired by design: one seed, the same initial weights and the same batches.

The comparison treats seed ``s`` of every variant as a pair (msdepth.stats); that holds
only while a variant changes nothing but the loss. These tests train each variant a few steps with
one seed and check what training actually saw, so a variant that draws random numbers before the
network is built, or that changes the data order, fails here.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

import msdepth.training.train as train_mod
from msdepth.config.params import params_from_dict
from msdepth.training.pairing import PAIRING_KEYS, pairing_status, tensors_sha256
from msdepth.training.train import TrainOptions, TrainOutputs, load_model, train_variant

H, W = 32, 64
VARIANTS = ("ssim", "msssim", "mix")


def _params(**msssim):
    return params_from_dict(
        {
            "data": {"height": H, "width": W},
            "model": {"width_multiplier": 0.0625},
            "train": {"epochs": 1, "batch_size": 4, "threads": 1},
            "msssim": {"levels": 3, **msssim},
            "mix": {"levels": 3},
            "variants": list(VARIANTS),
            "optimum": {"start": "constant"},  # mix has no per-pixel cost to match
        }
    )


def _first_step(monkeypatch, params, pairs, tmp: Path, variant: str, seed: int = 0) -> dict:
    """Train ``variant`` one epoch; return the weights and the batch its first step saw, and the
    training summary's pairing record."""
    seen: dict = {}
    real = train_mod._batch_losses

    def spy(run, batch):
        if not seen:
            seen["weights"] = tensors_sha256(sorted(run.model.state_dict().items()))
            seen["batch"] = tensors_sha256(sorted((k, v) for k, v in batch.items() if torch.is_tensor(v)))
        return real(run, batch)

    monkeypatch.setattr(train_mod, "_batch_losses", spy)
    out = tmp / f"{variant}{seed}"
    out.mkdir()
    train_variant(
        params,
        variant,
        pairs,
        TrainOutputs(out / "m.pt", out / "ck.pt", summary_path=out / "s.json"),
        TrainOptions(progress=False, seed=seed),
    )
    seen["record"] = json.loads((out / "s.json").read_text())["pairing"]
    return seen


def test_every_variant_starts_from_the_same_weights_and_batches(pairs, tmp_path: Path, monkeypatch) -> None:
    params = _params()
    runs = {v: _first_step(monkeypatch, params, pairs, tmp_path, v) for v in VARIANTS}
    ssim = runs["ssim"]
    assert sorted(ssim["record"]) == sorted(PAIRING_KEYS)
    for variant, seen in runs.items():
        assert seen["weights"] == ssim["weights"], f"{variant}: other initial weights than ssim's"
        assert seen["batch"] == ssim["batch"], f"{variant}: another first batch than ssim's"
        assert seen["record"] == ssim["record"], variant
    # The record is what the first step saw, and another seed changes both hashes.
    other = _first_step(monkeypatch, params, pairs, tmp_path, "ssim", seed=1)
    assert other["weights"] != ssim["weights"] and other["batch"] != ssim["batch"]
    assert other["record"]["initial_weights_sha256"] != ssim["record"]["initial_weights_sha256"]
    assert other["record"]["first_batch_sha256"] != ssim["record"]["first_batch_sha256"]


def test_a_variant_with_learned_weights_is_still_paired(pairs, tmp_path: Path, monkeypatch) -> None:
    """MS-SSIM's learned level weights are parameters of the loss, built after the network: the
    network's initial weights and the batches stay those of SSIM's run of the same seed."""
    ssim = _first_step(monkeypatch, _params(), pairs, tmp_path, "ssim")
    learned = _first_step(monkeypatch, _params(weights="learned"), pairs, tmp_path, "msssim")
    assert learned["record"] == ssim["record"]


def test_recording_the_pairing_leaves_the_trained_weights_unchanged(
    pairs, tmp_path: Path, monkeypatch
) -> None:
    params = _params()
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    train_variant(
        params,
        "ssim",
        pairs,
        TrainOutputs(tmp_path / "a" / "m.pt", tmp_path / "a" / "ck.pt"),
        TrainOptions(progress=False),
    )
    monkeypatch.setattr(train_mod, "_pairing", lambda *a: {})
    train_variant(
        params,
        "ssim",
        pairs,
        TrainOutputs(tmp_path / "b" / "m.pt", tmp_path / "b" / "ck.pt"),
        TrainOptions(progress=False),
    )
    a, b = (load_model(tmp_path / x / "m.pt")[0].state_dict() for x in "ab")
    assert tensors_sha256(sorted(a.items())) == tensors_sha256(sorted(b.items()))


RECORD = {"initial_weights_sha256": "a", "first_batch_sha256": "b"}


@pytest.mark.parametrize(
    ("change", "why"),
    [
        ({}, None),
        ({"initial_weights_sha256": "x"}, "seed0: the initial weights differ"),
        ({"first_batch_sha256": "x"}, "seed0: the first training batches differ"),
    ],
)
def test_pairing_status_pairs_only_runs_whose_records_agree(change: dict, why: str | None) -> None:
    summaries = {"v/seed0": {"pairing": {**RECORD, **change}}, "r/seed0": {"pairing": RECORD}}
    assert pairing_status({"v": ["v/seed0"], "r": ["r/seed0"]}, "r", summaries) == {"v": why}


def test_pairing_status_falls_back_for_other_seeds_or_no_record() -> None:
    groups = {"v": ["v/seed0", "v/seed1"], "r": ["r/seed0", "r/seed2"], "prior": ["prior"]}
    summaries = {r: {"pairing": RECORD} for runs in groups.values() for r in runs}
    status = pairing_status(groups, "r", summaries)
    assert status["v"] == "the two variants were trained with different seeds"
    assert status["prior"] == "a baseline is one deterministic run, not a seed of a variant"
    old = {"v/seed0": {}, "r/seed0": {"pairing": RECORD}}
    assert "no pairing record" in pairing_status({"v": ["v/seed0"], "r": ["r/seed0"]}, "r", old)["v"]
