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
"""

from __future__ import annotations

import argparse
import csv
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False, description=__doc__.split("\n\n")[0])
    parser.add_argument("--plans", type=int, default=240, help="training plans (default: 240)")
    parser.add_argument("--validation", type=int, default=16, help="validation plans (default: 16)")
    parser.add_argument("--minutes", type=float, default=60.0, help="training time budget (default: 60)")
    parser.add_argument("--batch", type=int, default=12)
    parser.add_argument("--eval-every", type=int, default=300)
    parser.add_argument("--out", type=Path, required=True, help="folder for the data cache, curve.csv and the ONNX file")
    args = parser.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    torch.manual_seed(0)
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
    optimiser = torch.optim.Adam(model.parameters(), lr=2e-3)
    budget_s = args.minutes * 60.0
    loss_fn = torch.nn.BCEWithLogitsLoss(pos_weight=torch.tensor(2.0))
    areas = np.array([image.size for image, _ in train], dtype=np.float64)
    curve = []
    started = time.time()
    step = 0
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
        # the learning rate falls along a cosine over the time budget
        for group in optimiser.param_groups:
            group["lr"] = 2e-3 * 0.5 * (1 + np.cos(np.pi * min(1.0, (time.time() - started) / budget_s)))
        model.train()
        loss = loss_fn(model(torch.from_numpy(batch_x)), torch.from_numpy(batch_y))
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        step += 1
        if step % args.eval_every == 0 or time.time() - started >= budget_s:
            model.eval()
            ious = [tolerant_iou(predict(model, image) > 0.5, walls > 0.5) for image, walls in validation]
            curve.append({"step": step, "minutes": round((time.time() - started) / 60, 2), "loss": float(loss.item()),
                          "validation_wall_iou": float(np.mean(ious))})
            print(curve[-1], flush=True)
            with (args.out / "curve.csv").open("w", newline="") as handle:
                writer = csv.DictWriter(handle, fieldnames=list(curve[0]))
                writer.writeheader()
                writer.writerows(curve)
            torch.save(model.state_dict(), args.out / "segmenter.pt")
    model.eval()
    dummy = torch.zeros(1, 1, 256, 256)
    torch.onnx.export(model, dummy, str(args.out / "segmenter.onnx"), opset_version=13, dynamo=False,
                      input_names=["darkness"], output_names=["wall_logit"],
                      dynamic_axes={"darkness": {2: "rows", 3: "cols"}, "wall_logit": {2: "rows", 3: "cols"}})
    net = cv2.dnn.readNetFromONNX(str(args.out / "segmenter.onnx"))  # OpenCV reads it: the reader can run it
    image = validation[0][0]
    rows, cols = (image.shape[0] // 8) * 8, (image.shape[1] // 8) * 8
    net.setInput(image[None, None, :rows, :cols].copy())
    ours = net.forward()[0, 0]
    theirs = predict(model, image[:rows, :cols])
    print(f"exported {args.out / 'segmenter.onnx'}: cv2.dnn and torch agree within "
          f"{np.abs(1 / (1 + np.exp(-ours)) - theirs).max():.2g}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
