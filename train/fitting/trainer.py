"""Self-supervised training loop (min-of-60 chamfer, Adam 5e-4), checkpoints + resume, validation, DDP.

Convention:
    Batches are [B, N, 3] float32 in model units (metres / scale), FPS-ordered; the loss never sees a pose label.
    Ground truth is used only to *report* the validation median rotation error (after a quick calibration on
    category-frame training inputs, spec §6); it never chooses a checkpoint (``latest.pt`` is always the newest).
    Output folder: ``latest.pt`` (the checkpoint format of ``checkpoint.py``), ``log.jsonl`` (one line per
    validation), ``config.json``.
    Distributed: ``torchrun --nproc_per_node K -m equipose.cli train ...`` (gloo on CPU, nccl on CUDA); every rank
    draws its own batches (seed + rank), gradients are averaged by DDP, rank 0 validates and saves.
"""
from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import time

import numpy as np
import torch
from tqdm import tqdm

from equipose.core.errors import ConfigError
from equipose.train.fitting.config import TrainConfig
from equipose.train.data.augment import rotate_views
from equipose.train.fitting.checkpoint import load_checkpoint, optimizer_to, save_checkpoint
from equipose.train.data.datasets import collate, make_dataset
from equipose.train.data.modelnet import MODELNET_SCALE, category_symmetry, default_data_root
from equipose.train.evaluation.inference import calibrate_model, predict_torch
from equipose.train.evaluation.calibration import apply_calibration
from equipose.eval.metrics import rotation_errors
from equipose.train.fitting.distill import (canonical_clouds, complete_clouds, is_view_teacher,
                                            teacher_targets, view_teacher_targets)
from equipose.train.fitting.losses import axial_symmetry_loss, chamfer_min_of_60_loss, distillation_loss
from equipose.train.network.model import EquiPoseNet

__all__ = ["train", "validate", "validation_inputs", "canonical_isotropy"]


def _dist_info() -> tuple:
    return tuple(int(os.environ.get(k, d)) for k, d in (("WORLD_SIZE", "1"), ("RANK", "0"), ("LOCAL_RANK", "0")))


def _render_opts(cfg: TrainConfig, split: str) -> dict:
    if split == "train" and cfg.sensor:
        return {"views": cfg.views, "sensor": True}
    return {"views": cfg.views if split == "train" else cfg.test_views}


def _dataset(cfg: TrainConfig, split: str, num_points: int):
    """The "train" or "test" split as the config asks (a ``train_limit`` also thins the validation instances)."""
    limit = cfg.train_limit if split == "train" or cfg.train_limit is None else max(2, cfg.val_size // 5)
    return make_dataset(cfg.data_root or str(default_data_root()), cfg.category, cfg.mode, split, num_points,
                        train=split == "train", limit=limit, cache_dir=cfg.cache_dir or None,
                        render_opts=_render_opts(cfg, split))


def _datasets(cfg: TrainConfig, num_points: int) -> tuple:
    return _dataset(cfg, "train", num_points), _dataset(cfg, "test", num_points)


def validation_inputs(train_ds, val_ds, cfg: TrainConfig) -> dict:
    """Fixed subsets: category-frame training inputs (calibration) and test samples (median rotation error)."""
    rng = np.random.default_rng(12345)
    ci = rng.choice(len(train_ds), size=min(cfg.calib_size, len(train_ds)), replace=False)
    calib = np.stack([train_ds.sample(int(i), np.random.default_rng(int(i)))["canonical"] for i in ci])
    vi = np.linspace(0, len(val_ds) - 1, min(cfg.val_size, len(val_ds))).round().astype(int)
    val = collate([val_ds[int(i)] for i in vi])
    return {"calib": calib, "val": val}


def validate(model, inputs: dict, symmetry: str, device) -> dict:
    """Quick calibration + median rotation error on the fixed validation subset (reporting only)."""
    cal = calibrate_model(model, inputs["calib"], symmetry=symmetry, unsigned_axis=False, device=device)
    R, t, _ = predict_torch(model, inputs["val"]["points"], device=device)
    Rh, _ = apply_calibration(R, t, cal)
    err = rotation_errors(Rh, inputs["val"]["rotation"], symmetry)
    return {"val_rot_median_deg": float(np.median(err)), "val_rot_mean_deg": float(err.mean()),
            "val_acc_5deg": float(np.mean(err <= 5)), "calib_inlier_fraction": cal["inlier_fraction"],
            "canon_isotropy": canonical_isotropy(model, inputs["val"]["points"][:8], device), "calibration": cal}


@torch.no_grad()
def canonical_isotropy(model, points: np.ndarray, device="cpu") -> float:
    """Collapse detector: median over inputs of (smallest / largest principal std) of the predicted canonical shape.

    Near 1 means a round blob that fits every view equally well in every orientation — the pose branch then learns
    nothing (seen with unidirectional partial-view chamfer on mugs); a category with a real shape stays well below 1.
    """
    was = model.training
    model.eval()
    c = model(torch.as_tensor(np.asarray(points), dtype=torch.float32, device=device))["canonical_shape"]
    model.train(was)
    c = c - c.mean(dim=1, keepdim=True)                                              # [B, M, 3]
    ev = torch.linalg.eigvalsh(c.transpose(1, 2) @ c / c.shape[1]).clamp_min(0).sqrt()   # [B, 3] ascending stds
    return float((ev[:, 0] / ev[:, 2].clamp_min(1e-12)).median())


def train(cfg: TrainConfig, resume: bool = False, log=print) -> pathlib.Path:
    """Run training; returns the path of ``latest.pt``."""
    world, rank, local = _dist_info()
    torch.set_num_threads(max(1, cfg.threads))
    if cfg.device:
        device = torch.device(cfg.device)
    else:
        device = torch.device(f"cuda:{local}" if torch.cuda.is_available() else "cpu")
    if world > 1 and not torch.distributed.is_initialized():
        torch.distributed.init_process_group("nccl" if device.type == "cuda" else "gloo")
    out = pathlib.Path(cfg.out)
    ckpt_path = out / "latest.pt"
    torch.manual_seed(cfg.seed)

    model = EquiPoseNet(cfg.preset, partial=(cfg.mode == "partial"))
    symmetry = category_symmetry(cfg.category)
    train_ds, val_ds = _datasets(cfg, model.num_points)
    scale = float(getattr(train_ds, "scale", MODELNET_SCALE))
    frozen = [f for f in (x.strip() for x in cfg.freeze.split(",")) if f]
    for name in frozen:
        sub = getattr(model, name, None)
        if not isinstance(sub, torch.nn.Module) or name.startswith("_"):
            raise ConfigError(f"--freeze {name!r}: not a submodule (blocks, pose_head, inv_head, decoder)")
        for prm in sub.parameters():
            prm.requires_grad_(False)
    opt = torch.optim.Adam([prm for prm in model.parameters() if prm.requires_grad], lr=cfg.lr)
    step, history, seconds = 0, [], []
    samples = None                                   # training samples seen over all slices (sets the lr epoch)
    calibration = None
    if resume and ckpt_path.is_file():
        ck = load_checkpoint(ckpt_path)
        model.load_state_dict(ck["state_dict"])
        if ck.get("optimizer"):
            opt.load_state_dict(ck["optimizer"])
        step = int(ck["step"])
        samples = ck.get("training", {}).get("samples_seen")
        history = ck.get("training", {}).get("history", [])
        seconds = ck.get("training", {}).get("step_seconds", [])
        calibration = ck.get("calibration")
        if rank == 0:
            log(f"resumed from {ckpt_path} at step {step}")
    elif resume and rank == 0:
        log(f"no checkpoint at {ckpt_path}; starting from scratch")
    if step == 0 and cfg.init:
        ck = load_checkpoint(cfg.init)
        try:
            model.load_state_dict(ck["state_dict"])
        except RuntimeError as e:
            raise ConfigError(f"--init {cfg.init}: weights do not fit preset {cfg.preset!r} / mode {cfg.mode!r} "
                              f"({str(e).splitlines()[0]})") from None
        if rank == 0:
            log(f"initialised from {cfg.init} (its step {ck.get('step')}, category {ck.get('category')!r})")
    model.to(device)
    optimizer_to(opt, device)                         # resumed Adam moments follow the parameters (CPU → CUDA)
    net = model
    if world > 1:
        net = torch.nn.parallel.DistributedDataParallel(model, device_ids=[local] if device.type == "cuda" else None)

    if rank == 0:
        out.mkdir(parents=True, exist_ok=True)
        (out / "config.json").write_text(json.dumps(dataclasses.asdict(cfg), indent=1))
        val_inputs = validation_inputs(train_ds, val_ds, cfg)
    targets = None
    if cfg.teacher:
        view_teacher = is_view_teacher(cfg.teacher)
        clouds = None
        if not view_teacher or cfg.cloud_weight > 0:  # the complete clouds: a complete teacher's input, the cloud term
            clouds = complete_clouds(cfg.data_root or str(default_data_root()), cfg.category, "train",
                                     cfg.train_limit)
            if len(clouds) <= int(train_ds.instance.max()):
                raise ConfigError(f"teacher: {len(clouds)} complete clouds for "
                                  f"{int(train_ds.instance.max()) + 1} instances")
        out.mkdir(parents=True, exist_ok=True)
        quiet = log if rank == 0 else (lambda *_: None)
        if view_teacher:                                # the same instances' clean views, through a partial model
            clean = train_ds if not cfg.sensor else _dataset(dataclasses.replace(cfg, sensor=False), "train",
                                                             model.num_points)
            tt = view_teacher_targets(cfg.teacher, train_ds, clean, symmetry, cache_file=out / "teacher.npz",
                                      log=quiet)
        else:
            tt = teacher_targets(cfg.teacher, train_ds, clouds, refine=cfg.teacher_refine,
                                 cache_file=out / "teacher.npz", frame_priors=cfg.teacher_priors,
                                 flip_model=cfg.teacher_flip, log=quiet)
        tt = {**tt, "clouds": canonical_clouds(clouds, tt, train_ds)} if cfg.cloud_weight > 0 else tt   # + [I, K, 3]
        targets = {k: torch.from_numpy(np.asarray(v, np.int64 if k == "instance" else np.float32)).to(device)
                   for k, v in tt.items()}
    rng = np.random.default_rng([cfg.seed, rank, step])
    if samples is None:                              # a checkpoint from before the count: its steps at this batch
        samples = step * cfg.batch_size * world

    def summary():
        return {"category": cfg.category, "mode": cfg.mode, "preset": cfg.preset, "batch_size": cfg.batch_size,
                "world_size": world, "train_samples": len(train_ds), "lr": cfg.lr, "device": str(device),
                "samples_seen": int(samples),
                "threads": cfg.threads, "history": history, "step_seconds": seconds[-1000:],
                "seconds_per_step_median": float(np.median(seconds[3:] or seconds)) if seconds else None,
                "data_root": cfg.data_root or str(default_data_root()), "config": dataclasses.asdict(cfg)}

    def save():
        save_checkpoint(ckpt_path, model, category=cfg.category, scale=scale, symmetry=symmetry, step=step,
                        optimizer=opt, calibration=calibration, training=summary())

    spent = 0.0                                      # training-step seconds of this invocation (``minutes`` budget)
    bar = tqdm(total=cfg.steps, initial=min(step, cfg.steps), disable=rank != 0,
               desc=f"train {cfg.category}/{cfg.mode}", dynamic_ncols=True)
    while step < cfg.steps:
        net.train()
        for name in frozen:                          # frozen = fixed weights *and* fixed BatchNorm statistics
            getattr(model, name).eval()
        lr = cfg.lr * cfg.lr_gamma ** (samples // len(train_ds))   # decays per epoch of samples, whatever the batch
        for g in opt.param_groups:
            g["lr"] = lr
        t0 = time.perf_counter()
        idx = rng.integers(0, len(train_ds), cfg.batch_size)
        batch = collate([train_ds.sample(int(i), rng) for i in idx])
        x = torch.from_numpy(batch["points"]).to(device)
        if targets is None:
            pred = net(x, return_aux=True)
            loss = chamfer_min_of_60_loss(pred)
            if cfg.symmetry_weight and symmetry != "none":
                loss = loss + cfg.symmetry_weight * axial_symmetry_loss(pred["canonical_shape"], rng)
        else:
            v = torch.from_numpy(idx).to(device)
            R_t, t_t = targets["rotations"][v], targets["translations"][v]            # [B, 3, 3], [B, 3]
            x, R_t, t_t = rotate_views(x, R_t, t_t, rng) if cfg.rotate_augment else (x, R_t, t_t)
            inst = targets["instance"][v]
            loss, _ = distillation_loss(net(x, return_aux=True), targets["shapes"][inst], R_t, t_t,
                                        model.anchors, symmetric=symmetry != "none", select_weight=cfg.select_weight,
                                        shape_weight=cfg.shape_weight, points=x, view_weight=cfg.view_weight,
                                        drift_weight=cfg.drift_weight, drift_iters=cfg.drift_iters,
                                        cloud_weight=cfg.cloud_weight,
                                        clouds=targets["clouds"][inst] if cfg.cloud_weight else None)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        step += 1
        samples += cfg.batch_size * world
        seconds.append(time.perf_counter() - t0)
        spent += seconds[-1]
        bar.update(1)
        bar.set_postfix(loss=f"{loss.item():.5f}", s_step=f"{seconds[-1]:.2f}")
        last = step == cfg.steps or (cfg.minutes > 0 and spent >= 60.0 * cfg.minutes)
        if rank == 0 and (step % cfg.val_every == 0 or last):
            v = validate(model, val_inputs, symmetry, device)
            calibration = v.pop("calibration")
            rec = {"step": step, "loss": float(loss.item()), "lr": lr, "train_minutes": spent / 60.0, **v}
            history.append(rec)
            with open(out / "log.jsonl", "a") as f:
                f.write(json.dumps(rec) + "\n")
            bar.write(f"step {step}: loss {rec['loss']:.5f}  val median rot {v['val_rot_median_deg']:.1f}°  "
                      f"5° {v['val_acc_5deg']:.2f}  calib inliers {v['calib_inlier_fraction']:.2f}")
        if rank == 0 and (step % cfg.ckpt_every == 0 or last):
            save()
        if world > 1 and (last or step % cfg.val_every == 0):
            torch.distributed.barrier()
        if last:
            break
    bar.close()
    if rank == 0 and not ckpt_path.is_file():
        save()
    if world > 1:
        torch.distributed.barrier()
        torch.distributed.destroy_process_group()
    return ckpt_path
