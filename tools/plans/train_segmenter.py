#!/usr/bin/env python3
"""Train a small wall/free segmentation network on generated plans only, and export it to ONNX.

The network sees a plan as the drawing reader does (the paper evened, `mapfilter.maps.drawing.
even_paper`), resampled to ``WORK_M`` metres per pixel, and gives each pixel the probability
that it is wall (walls, windows, columns: the generator's exact truth). It is a small U-Net
(three poolings, dilated convolutions at the bottom, about 0.1 M weights) trained with Adam on
random 128 x 128 patches, flips and quarter turns, from plans of the training seed (never the
benchmark's held-out seed); every ``--eval-every`` steps the wall IoU (2 px) on plans of a
validation seed is recorded in curve.csv. The weights are exported for OpenCV's ``cv2.dnn``
(ONNX, opset 13). Its extra dependencies (torch, onnx) are in tools/plans/requirements-train.txt;
no user needs them:

    python3 -m venv .venv-train && .venv-train/bin/pip install -r tools/plans/requirements-train.txt -e .
    nice -n 10 .venv-train/bin/python tools/plans/train_segmenter.py --plans 240 --minutes 60 --out /tmp/seg

It writes checkpoint.pt (model, optimiser state, step count, the curve so far) to --out every
``--checkpoint-every`` steps and at the end, so a run cut off is not lost: ``--resume`` continues
from one (into another --out) with a new cosine over the new --minutes; ``--minutes 0``
only exports its ONNX file:

    nice -n 10 .venv-train/bin/python tools/plans/train_segmenter.py --resume /tmp/seg/checkpoint.pt --lr 1e-3 --minutes 60 --out /tmp/seg2
"""

from __future__ import annotations

import argparse
import csv
import pickle
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import plangen  # noqa: E402

WORK_M = 0.025  # the network's metres per pixel
TRAIN_SEED, VALIDATION_SEED = 101, 103  # neither is the benchmark's held-out seed
PATCH = 128


def plan_arrays(seed_sequence, index: int) -> tuple[np.ndarray, np.ndarray]:
    """(evened image, wall share) of one generated plan at ``WORK_M`` per pixel, float32."""
    from mapfilter.maps.drawing import even_paper

    plan = plangen.generate_plan(seed_sequence, plangen.style_of(index))
    gray = plan.image if plan.image.ndim == 2 else cv2.cvtColor(plan.image, cv2.COLOR_BGR2GRAY)
    if plan.jpeg is not None:
        gray = cv2.imdecode(np.frombuffer(plan.jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
    evened = even_paper(gray, plan.resolution_m)
    return network_input(evened, plan.resolution_m), resample(plan.walls.astype(np.float32), plan.resolution_m)


def resample(image: np.ndarray, resolution_m: float) -> np.ndarray:
    rows, cols = image.shape
    factor = resolution_m / WORK_M
    size = (max(8, round(cols * factor)), max(8, round(rows * factor)))
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA if factor < 1 else cv2.INTER_LINEAR)


def network_input(evened: np.ndarray, resolution_m: float) -> np.ndarray:
    """The darkness (0 paper, 1 black) at ``WORK_M`` per pixel."""
    return resample((255.0 - evened.astype(np.float32)) / 255.0, resolution_m)


def build_model():
    import torch
    from torch import nn

    def block(cin, cout, dilation=1):
        return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=dilation, dilation=dilation), nn.BatchNorm2d(cout),
                             nn.ReLU(inplace=True), nn.Conv2d(cout, cout, 3, padding=dilation, dilation=dilation),
                             nn.BatchNorm2d(cout), nn.ReLU(inplace=True))

    class UNet(nn.Module):
        def __init__(self):
            super().__init__()
            self.e1, self.e2, self.e3 = block(1, 12), block(12, 24), block(24, 40)
            self.bottom = nn.Sequential(block(40, 56, 2), block(56, 56, 4))
            self.d3, self.d2, self.d1 = block(56 + 40, 40), block(40 + 24, 24), block(24 + 12, 12)
            self.head = nn.Conv2d(12, 1, 1)
            self.pool = nn.MaxPool2d(2)
            self.up = nn.Upsample(scale_factor=2, mode="nearest")

        def forward(self, x):
            a = self.e1(x)
            b = self.e2(self.pool(a))
            c = self.e3(self.pool(b))
            d = self.bottom(self.pool(c))
            c = self.d3(torch.cat([self.up(d), c], 1))
            b = self.d2(torch.cat([self.up(c), b], 1))
            a = self.d1(torch.cat([self.up(b), a], 1))
            return self.head(a)  # logits

    return UNet()


def tolerant_iou(pred: np.ndarray, true: np.ndarray, tol_px: int = 2) -> float:
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * tol_px + 1, 2 * tol_px + 1))
    near_pred = cv2.dilate(pred.astype(np.uint8), disc).astype(bool)
    near_true = cv2.dilate(true.astype(np.uint8), disc).astype(bool)
    found, missed = (true & near_pred).sum(), (true & ~near_pred).sum()
    spurious = (pred & ~near_true).sum()
    return float(found / max(found + missed + spurious, 1))


def predict(model, image: np.ndarray) -> np.ndarray:
    """Wall probability of a whole image (padded to a multiple of 8)."""
    import torch

    rows, cols = image.shape
    padded = np.zeros(((rows + 7) // 8 * 8, (cols + 7) // 8 * 8), np.float32)
    padded[:rows, :cols] = image
    with torch.no_grad():
        logits = model(torch.from_numpy(padded)[None, None])
    return torch.sigmoid(logits)[0, 0, :rows, :cols].numpy()


def save_checkpoint(path: Path, model, optimiser, step: int, minutes: float, curve: list[dict], rng) -> None:
    """Model, optimiser state, step count, training minutes so far and the curve, written whole or not at all."""
    import torch

    partial = path.with_name(path.name + ".partial")
    torch.save({"model": model.state_dict(), "optimiser": optimiser.state_dict(), "step": step, "minutes": minutes,
                "curve": curve, "rng": rng.bit_generator.state, "torch_rng": torch.get_rng_state()}, partial)
    partial.replace(path)


def load_checkpoint(path: Path) -> dict:
    """A checkpoint of this script, or a bare ``state_dict`` (step, minutes and curve then come from the
    curve.csv beside it, if there is one; the optimiser state starts fresh)."""
    import torch

    try:
        loaded = torch.load(path, map_location="cpu", weights_only=False)
    except (OSError, RuntimeError, EOFError, ValueError, pickle.UnpicklingError) as error:
        raise SystemExit(f"error: {path}: not a checkpoint ({error})") from None
    if isinstance(loaded, dict) and "model" in loaded:
        return loaded
    if not isinstance(loaded, dict) or not all(isinstance(v, torch.Tensor) for v in loaded.values()):
        raise SystemExit(f"error: {path}: neither a checkpoint nor a state_dict")
    curve = []
    beside = path.with_name("curve.csv")
    if beside.exists():
        with beside.open(newline="") as handle:
            curve = [{"step": int(row["step"]), "minutes": float(row["minutes"]), "loss": float(row["loss"]),
                      "validation_wall_iou": float(row["validation_wall_iou"])} for row in csv.DictReader(handle)]
    return {"model": loaded, "optimiser": None, "step": curve[-1]["step"] if curve else 0,
            "minutes": curve[-1]["minutes"] if curve else 0.0, "curve": curve, "rng": None, "torch_rng": None}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("--plans", type=int, default=240, help="training plans (default: 240)")
    parser.add_argument("--validation", type=int, default=16, help="validation plans (default: 16)")
    parser.add_argument("--minutes", type=float, default=60.0, help="training time budget of this run (default: 60)")
    parser.add_argument("--lr", type=float, default=2e-3, help="peak learning rate of this run's cosine (default: 2e-3)")
    parser.add_argument("--batch", type=int, default=12)
    parser.add_argument("--eval-every", type=int, default=300)
    parser.add_argument("--checkpoint-every", type=int, default=100, help="steps between checkpoints (default: 100)")
    parser.add_argument("--resume", type=Path, help="continue from this checkpoint (or a bare state_dict)")
    parser.add_argument("--out", type=Path, required=True,
                        help="folder for the data cache, checkpoint.pt, curve.csv and the ONNX file")
    args = parser.parse_args(argv)
    import torch

    if args.resume is not None and args.resume.resolve().parent == args.out.resolve():
        parser.error(f"--resume {args.resume}: this run writes into its folder; give another --out")
    torch.set_num_threads(1)
    torch.manual_seed(0)
    resumed = load_checkpoint(args.resume) if args.resume is not None else None
    args.out.mkdir(parents=True, exist_ok=True)
    cache = args.out / f"data_{args.plans}_{args.validation}.npz"
    if cache.exists():
        data = np.load(cache, allow_pickle=True)
        train, validation = list(data["train"]), list(data["validation"])
    else:
        started = time.time()
        train = [plan_arrays(s, i) for i, s in enumerate(plangen.plan_seeds(TRAIN_SEED, args.plans))]
        validation = [plan_arrays(s, i) for i, s in enumerate(plangen.plan_seeds(VALIDATION_SEED, args.validation))]
        holder = np.empty(len(train), dtype=object)
        holder[:] = train
        vholder = np.empty(len(validation), dtype=object)
        vholder[:] = validation
        np.savez(cache, train=holder, validation=vholder)
        print(f"data: {len(train)} + {len(validation)} plans in {time.time() - started:.0f} s", flush=True)
    rng = np.random.default_rng(0)
    model = build_model()
    optimiser = torch.optim.Adam(model.parameters(), lr=args.lr)
    curve, step, minutes_before = [], 0, 0.0
    if resumed is not None:
        model.load_state_dict(resumed["model"])
        if resumed["optimiser"] is not None:
            optimiser.load_state_dict(resumed["optimiser"])
        curve, step, minutes_before = list(resumed["curve"]), int(resumed["step"]), float(resumed["minutes"])
        if resumed["rng"] is not None:
            rng.bit_generator.state = resumed["rng"]
            torch.set_rng_state(resumed["torch_rng"])
        else:  # no stored draws: other patches than the first run's first ones, still the same for the same input
            rng = np.random.default_rng([0, step])
        print(f"resumed {args.resume} at step {step} ({minutes_before:.1f} min trained, optimiser state "
              f"{'restored' if resumed['optimiser'] is not None else 'fresh'})", flush=True)
    budget_s = args.minutes * 60.0
    loss_fn = torch.nn.BCEWithLogitsLoss(pos_weight=torch.tensor(2.0))
    areas = np.array([image.size for image, _ in train], dtype=np.float64)
    started = time.time()
    run_steps = 0
    while time.time() - started < budget_s:
        batch_x = np.zeros((args.batch, 1, PATCH, PATCH), np.float32)
        batch_y = np.zeros_like(batch_x)
        for k in range(args.batch):
            image, walls = train[rng.choice(len(train), p=areas / areas.sum())]
            rows, cols = image.shape
            r = rng.integers(0, max(1, rows - PATCH + 1))
            c = rng.integers(0, max(1, cols - PATCH + 1))
            x, y = image[r:r + PATCH, c:c + PATCH], walls[r:r + PATCH, c:c + PATCH]
            turns = int(rng.integers(4))
            x, y = np.rot90(x, turns), np.rot90(y, turns)
            if rng.random() < 0.5:
                x, y = x[:, ::-1], y[:, ::-1]
            batch_x[k, 0, :x.shape[0], :x.shape[1]] = x
            batch_y[k, 0, :y.shape[0], :y.shape[1]] = y
        # the learning rate falls along a cosine over this run's time budget (a resumed run is a warm
        # restart); a fresh optimiser state first warms up over 100 steps so its first steps do not undo the weights
        warm = min(1.0, (run_steps + 1) / 100) if resumed is not None and resumed["optimiser"] is None else 1.0
        for group in optimiser.param_groups:
            group["lr"] = warm * args.lr * 0.5 * (1 + np.cos(np.pi * min(1.0, (time.time() - started) / budget_s)))
        model.train()
        loss = loss_fn(model(torch.from_numpy(batch_x)), torch.from_numpy(batch_y))
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        step += 1
        run_steps += 1
        minutes = minutes_before + (time.time() - started) / 60
        finished = time.time() - started >= budget_s
        if step % args.eval_every == 0 or finished:
            model.eval()
            ious = [tolerant_iou(predict(model, image) > 0.5, walls > 0.5) for image, walls in validation]
            curve.append({"step": step, "minutes": round(minutes, 2), "loss": float(loss.item()),
                          "validation_wall_iou": float(np.mean(ious))})
            print(curve[-1], flush=True)
            with (args.out / "curve.csv").open("w", newline="") as handle:
                writer = csv.DictWriter(handle, fieldnames=list(curve[0]))
                writer.writeheader()
                writer.writerows(curve)
            torch.save(model.state_dict(), args.out / "segmenter.pt")
        if step % args.checkpoint_every == 0 or finished:
            save_checkpoint(args.out / "checkpoint.pt", model, optimiser, step, minutes, curve, rng)
    model.eval()
    export_onnx(model, args.out / "segmenter.onnx", validation[0][0])
    return 0


def export_onnx(model, path: Path, image: np.ndarray) -> None:
    """Write the ONNX file and check that OpenCV's ``cv2.dnn`` reads it and agrees with torch."""
    import torch

    dummy = torch.zeros(1, 1, 256, 256)
    torch.onnx.export(model, dummy, str(path), opset_version=13, dynamo=False,
                      input_names=["darkness"], output_names=["wall_logit"],
                      dynamic_axes={"darkness": {2: "rows", 3: "cols"}, "wall_logit": {2: "rows", 3: "cols"}})
    net = cv2.dnn.readNetFromONNX(str(path))  # OpenCV reads it: the reader can run it
    rows, cols = (image.shape[0] // 8) * 8, (image.shape[1] // 8) * 8
    net.setInput(image[None, None, :rows, :cols].copy())
    ours = net.forward()[0, 0]
    theirs = predict(model, image[:rows, :cols])
    print(f"exported {path}: cv2.dnn and torch agree within "
          f"{np.abs(1 / (1 + np.exp(-ours)) - theirs).max():.2g}", flush=True)


if __name__ == "__main__":
    sys.exit(main())
