"""The training recipes of the objects screen (studies/results/objects/) at equal cost: one full
training step (network + loss + backward + Adam) of each, interleaved, with its time per step and
per image relative to the default's.

    python benchmarks/recipes.py                   # params.yaml's model, size, batch and threads
    python benchmarks/recipes.py --set loss.full_resolution=true --set model.architecture=resnet18

Candidates: the default (params.yaml), then each recipe that changes what a step costs:
``loss.full_resolution``, ``model.architecture: resnet18`` and half the batch (``train.batch_size``
/ 2; a screen that halves the batch doubles the steps). A learning-rate schedule or the smoothness
weight costs nothing per step, so it is not a candidate. Each candidate builds the network and
loss the training loop builds (``msdepth.training.train.build_model``,
``msdepth.losses.objective.build_loss``) on a random stereo batch of its own size.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Callable

import torch
from _timing import compare, table

from msdepth.config.params import Params, apply_overrides, params_from_dict, read_params_file
from msdepth.losses.objective import build_loss
from msdepth.training.train import build_model, forward_and_loss

ROOT = Path(__file__).resolve().parents[1]
RECIPES = {
    "full resolution loss": ["loss.full_resolution=true"],
    "resnet18": ["model.architecture=resnet18"],
}


def step_of(params: Params, batch: int) -> Callable[[], None]:
    """One SSIM training step of ``params``' network and loss on a random ``batch``."""
    torch.manual_seed(0)
    model = build_model(params)
    criterion = build_loss(params, "ssim")
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-6)  # tiny: weights barely move between repeats
    gen = torch.Generator().manual_seed(0)
    left = torch.rand(batch, 3, params.data.height, params.data.width, generator=gen)
    right = torch.roll(left, shifts=-3, dims=-1)

    def step() -> None:
        losses = forward_and_loss(model, criterion, left, right)
        optimizer.zero_grad(set_to_none=True)
        losses["total"].backward()
        optimizer.step()

    return step


def candidates(raw: dict) -> tuple[dict[str, Callable[[], None]], dict[str, int]]:
    """Each candidate's step and batch: the default, :data:`RECIPES`, half the batch."""
    base = params_from_dict(raw)
    steps, batches = {"default": step_of(base, base.train.batch_size)}, {"default": base.train.batch_size}
    for name, overrides in RECIPES.items():
        params = params_from_dict(apply_overrides(raw, overrides))
        steps[name], batches[name] = step_of(params, params.train.batch_size), params.train.batch_size
    half = max(1, base.train.batch_size // 2)
    steps[f"batch {half}"], batches[f"batch {half}"] = step_of(base, half), half
    return steps, batches


def main(argv: list[str] | None = None) -> None:
    """Time the candidates; print the step table and the per-image cost relative to the default."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="on every candidate")
    ap.add_argument("--repeats", type=int, default=15)
    args = ap.parse_args(argv)
    raw = apply_overrides(read_params_file(args.params), args.set)
    base = params_from_dict(raw)
    threads = base.train.threads
    torch.set_num_threads(threads)
    steps, batches = candidates(raw)
    timings = compare(steps, torch.device("cpu"), repeats=args.repeats)
    print(
        f"training step, {base.data.height}x{base.data.width}, model x{base.model.width_multiplier}, "
        f"cpu, {threads} threads, median of {args.repeats}\n"
    )
    print(table(timings, "default"))
    medians = timings.medians()
    per_image = {n: medians[n] / batches[n] for n in medians}
    print(
        "\ntime per image / default's: "
        + ", ".join(f"{n} {per_image[n] / per_image['default']:.2f}" for n in per_image)
    )


if __name__ == "__main__":
    main()
