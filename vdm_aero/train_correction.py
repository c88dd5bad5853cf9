"""Offline training of the correction net (PyTorch) and its export to one self-contained ONNX file.

This is the only module that imports torch; run-time code (``vdm_aero.model``) never does. The
training follows the method: ReLU MLP on port Cp, target = truth − DEIM prediction, Adam (lr 1e-3),
StepLR (step 50 epochs, γ 0.95), weight decay, mini-batches of 64, early stopping with patience 100
epochs on the validation cases (best weights restored). The input and output standardisation is
part of the exported graph, so run time feeds raw Cp and gets coefficient corrections.
"""

from __future__ import annotations

import itertools
import math
import tempfile
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from vdm_aero._typing import F64Array, FloatArray

LEARNING_RATE = 1e-3
LR_STEP_EPOCHS, LR_GAMMA = 50, 0.95
BATCH_SIZE = 64
PATIENCE_EPOCHS = 100
ONNX_MATCH_ATOL = 1e-5  # onnxruntime vs torch, absolute, in coefficient units
NOISY_VAL_REPLICAS = 4
_STD_FLOOR = 1e-8  # a constant input/target (e.g. CY of a 2-D section) is passed through unscaled


@dataclass(frozen=True)
class NetConfig:
    hidden_layers: int
    width: int
    weight_decay: float

    @property
    def label(self) -> str:
        return f"{self.hidden_layers}x{self.width} wd={self.weight_decay:g}"


GRIDS: dict[str, tuple[NetConfig, ...]] = {
    "paper": tuple(
        NetConfig(h, w, wd) for h, w, wd in itertools.product((2, 3, 4), (10, 20, 30, 40), (1e-5, 1e-6, 1e-7))
    ),
    "quick": (NetConfig(2, 20, 1e-6), NetConfig(3, 40, 1e-6)),
    "single": (NetConfig(3, 40, 1e-6),),  # `demo --quick`: a first look, no search
}


class CorrectionNet(nn.Module):
    """Standardise → ReLU MLP → de-standardise, all inside the graph."""

    x_mean: torch.Tensor
    x_scale: torch.Tensor
    y_mean: torch.Tensor
    y_std: torch.Tensor

    def __init__(self, cfg: NetConfig, x_mean: F64Array, x_std: F64Array, y_mean: F64Array, y_std: F64Array):
        super().__init__()
        f32 = torch.float32
        self.register_buffer("x_mean", torch.tensor(x_mean, dtype=f32))
        self.register_buffer("x_scale", torch.tensor(1.0 / x_std, dtype=f32))
        self.register_buffer("y_mean", torch.tensor(y_mean, dtype=f32))
        self.register_buffer("y_std", torch.tensor(y_std, dtype=f32))
        layers: list[nn.Module] = []
        n = len(x_mean)
        for _ in range(cfg.hidden_layers):
            layers += [nn.Linear(n, cfg.width), nn.ReLU()]
            n = cfg.width
        layers.append(nn.Linear(n, len(y_mean)))
        self.mlp = nn.Sequential(*layers)

    def forward_standardised(self, x: torch.Tensor) -> torch.Tensor:
        return self.mlp((x - self.x_mean) * self.x_scale)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.forward_standardised(x) * self.y_std + self.y_mean


@dataclass
class TrainResult:
    config: NetConfig
    net: CorrectionNet
    val_mse: float  # validation MSE in coefficient units² (mean over outputs)
    train_mse: float
    epochs: int
    best_epoch: int
    seconds: float


def _init_weights(net: nn.Module, gen: torch.Generator) -> None:
    # PyTorch's default Linear init, drawn from an explicit generator
    for m in net.modules():
        if isinstance(m, nn.Linear):
            nn.init.kaiming_uniform_(m.weight, a=math.sqrt(5), generator=gen)
            bound = 1.0 / math.sqrt(m.in_features)
            nn.init.uniform_(m.bias, -bound, bound, generator=gen)


def train_one(
    cfg: NetConfig,
    x_train: FloatArray,
    y_train: FloatArray,
    x_val: FloatArray,
    y_val: FloatArray,
    *,
    rng: np.random.Generator,
    max_epochs: int = 3000,
    input_noise: float = 0.0,
    linear_ms: F64Array | None = None,
) -> TrainResult:
    """Train one configuration with early stopping on the validation set.

    ``input_noise`` > 0 augments every mini-batch with fresh multiplicative Gaussian noise on the
    inputs, Cp·(1 + σ·N(0,1)) — the port noise model. The target of a noisy sample is the residual
    of the linear model *on that noisy input*, truth − (M_s·x̃ + M_0) = r − M_s·(x̃ − x), so the net
    learns to cancel the noise the linear part propagates as well (``linear_ms`` = M_s is required
    then). Validation then uses the clean validation set plus ``NOISY_VAL_REPLICAS`` fixed noisy
    replicas of it (drawn once), so early stopping and model selection favour noise-robust nets.
    """
    if input_noise > 0.0 and linear_ms is None:
        raise ValueError("input-noise augmentation needs the linear model's M_s to form noisy targets")
    t0 = time.perf_counter()
    x_mean, x_std = x_train.mean(0), x_train.std(0)
    y_mean, y_std = y_train.mean(0), y_train.std(0)
    x_std = np.where(x_std > _STD_FLOOR, x_std, 1.0)
    y_std = np.where(y_std > _STD_FLOOR, y_std, 1.0)
    net = CorrectionNet(cfg, x_mean, x_std, y_mean, y_std)
    gen = torch.Generator().manual_seed(int(rng.integers(2**62)))
    _init_weights(net, gen)
    xt = torch.tensor(x_train, dtype=torch.float32)
    yt = torch.tensor((y_train - y_mean) / y_std, dtype=torch.float32)
    xv = torch.tensor(x_val, dtype=torch.float32)
    yv = torch.tensor((y_val - y_mean) / y_std, dtype=torch.float32)
    ms_scaled = None if linear_ms is None else torch.tensor(np.asarray(linear_ms).T / y_std, dtype=torch.float32)
    if input_noise > 0.0 and ms_scaled is not None:
        xs, ys = [xv], [yv]
        for _ in range(NOISY_VAL_REPLICAS):
            dx = xv * (input_noise * torch.from_numpy(rng.standard_normal(tuple(xv.shape), dtype=np.float32)))
            xs.append(xv + dx)
            ys.append(yv - dx @ ms_scaled)
        xv, yv = torch.cat(xs), torch.cat(ys)
    opt = torch.optim.Adam(net.parameters(), lr=LEARNING_RATE, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.StepLR(opt, step_size=LR_STEP_EPOCHS, gamma=LR_GAMMA)
    loss_fn = nn.MSELoss()
    best, best_epoch, best_state = math.inf, -1, None
    n = len(xt)
    epoch = 0
    for epoch in range(max_epochs):
        net.train()
        perm = torch.from_numpy(rng.permutation(n))
        for lo in range(0, n, BATCH_SIZE):
            idx = perm[lo : lo + BATCH_SIZE]
            xb, yb = xt[idx], yt[idx]
            if input_noise > 0.0 and ms_scaled is not None:
                dx = xb * (input_noise * torch.from_numpy(rng.standard_normal(xb.shape, dtype=np.float32)))
                xb, yb = xb + dx, yb - dx @ ms_scaled
            opt.zero_grad(set_to_none=True)
            loss = loss_fn(net.forward_standardised(xb), yb)
            loss.backward()
            opt.step()
        sched.step()
        net.eval()
        with torch.no_grad():
            v = float(loss_fn(net.forward_standardised(xv), yv))
        if v < best:
            best, best_epoch = v, epoch
            best_state = {k: t.detach().clone() for k, t in net.state_dict().items()}
        elif epoch - best_epoch >= PATIENCE_EPOCHS:
            break
    if best_state is None:  # every validation loss was NaN: no validation samples, or non-finite ones
        raise ValueError(f"the validation loss is not finite ({len(x_val)} validation samples): nothing to select on")
    net.load_state_dict(best_state)
    net.eval()
    with torch.no_grad():
        y_scale = torch.tensor(y_std, dtype=torch.float32)
        val_mse = float(((net.forward_standardised(xv) - yv) * y_scale).pow(2).mean())
        train_mse = float(((net.forward_standardised(xt) - yt) * y_scale).pow(2).mean())
    return TrainResult(cfg, net, val_mse, train_mse, epoch + 1, best_epoch + 1, time.perf_counter() - t0)


def grid_search(
    configs: Sequence[NetConfig],
    x_train: FloatArray,
    y_train: FloatArray,
    x_val: FloatArray,
    y_val: FloatArray,
    *,
    seed: int,
    max_epochs: int = 3000,
    input_noise: float = 0.0,
    linear_ms: F64Array | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[TrainResult, list[dict[str, Any]]]:
    """Train every configuration (each from its own seeded generator); select by validation MSE."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # tiny nets: one thread is fastest and leaves the other core free
    try:
        results = []
        for i, cfg in enumerate(configs):
            rng = np.random.default_rng([seed, i])
            results.append(
                train_one(
                    cfg,
                    x_train,
                    y_train,
                    x_val,
                    y_val,
                    rng=rng,
                    max_epochs=max_epochs,
                    input_noise=input_noise,
                    linear_ms=linear_ms,
                )
            )
            if progress is not None:
                progress(i + 1, len(configs))
    finally:
        torch.set_num_threads(threads)
    best = min(results, key=lambda r: r.val_mse)
    table = [
        {
            **asdict(r.config),
            "val_mse": r.val_mse,
            "train_mse": r.train_mse,
            "epochs": r.epochs,
            "best_epoch": r.best_epoch,
            "seconds": round(r.seconds, 2),
        }
        for r in results
    ]
    return best, table


def export_onnx(net: CorrectionNet, n_inputs: int) -> bytes:
    """One self-contained ONNX graph (weights inline), dynamic batch, input ``cp`` → output ``dcoeffs``.

    Uses torch's ``torch.export``-based exporter (the TorchScript one is deprecated since 2.9). Its
    op-registry warnings about absent torchvision are silenced for the duration of the call only.
    """
    import logging

    net.eval()
    quiet = logging.getLogger("torch.onnx")
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            # torch's own pytree deprecation notice (LeafSpec), not actionable here
            warnings.filterwarnings("ignore", category=FutureWarning, message=".*LeafSpec.*")
            program = torch.onnx.export(
                net,
                (torch.zeros(1, n_inputs, dtype=torch.float32),),
                dynamo=True,
                input_names=["cp"],
                output_names=["dcoeffs"],
                dynamic_shapes=({0: torch.export.Dim("batch")},),
                verbose=False,
            )
    finally:
        quiet.setLevel(level)
    if program is None:
        raise RuntimeError("torch.onnx.export returned no program")
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "net.onnx"
        program.save(str(path), external_data=False)
        if len(list(Path(d).iterdir())) != 1:
            raise RuntimeError("ONNX export wrote an external data file; the artifact must be one file")
        return path.read_bytes()


def check_onnx_matches(onnx_bytes: bytes, net: CorrectionNet, x: FloatArray) -> float:
    """Max |onnxruntime − torch| on inputs ``x``; raises if above ``ONNX_MATCH_ATOL``."""
    from vdm_aero.onnx_net import OnnxCorrection

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "net.onnx"
        p.write_bytes(onnx_bytes)
        ort_out = OnnxCorrection(p).predict_batch(x)
    with torch.no_grad():
        torch_out = net(torch.tensor(np.asarray(x), dtype=torch.float32)).double().numpy()
    err = float(np.max(np.abs(ort_out - torch_out)))
    if not err <= ONNX_MATCH_ATOL:
        raise RuntimeError(f"exported ONNX graph differs from torch by {err:.2e} > {ONNX_MATCH_ATOL:g}")
    return err
