"""lghcc-train's files: the training state (``STATE_NAME``: everything needed to resume
exactly), the checkpoint folders ``point_cloud/iteration_<N>/`` (the scene in the Scaffold-GS
layout, written atomically), and the metrics files (metrics.json, metrics.csv)."""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import os
import shutil
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ...app.fileio import atomic_write_bytes
from ...common.errors import InputError
from ...common.scene import AnchorScene
from ...formats.scaffold_io import write_scaffold
from .parameters import make_mlp

STATE_NAME = "train_state.pth"
STATE_VERSION = 1
TMP_PREFIX = ".tmp_"  # point_cloud/.tmp_iteration_<N>_<pid>: a checkpoint folder being written
OLD_PREFIX = ".old_"  # point_cloud/.old_iteration_<N>_<pid>: a replaced folder about to be removed


class CheckpointState:
    """Saving and restoring a ``Trainer`` (training/loop.py): ``state_dict`` holds its parameters,
    Adam state, statistics, RNG states and history; ``save_checkpoint`` writes every file of the run."""

    def state_dict(self) -> dict:
        return {
            "version": STATE_VERSION, "config": dataclasses.asdict(self.cfg), "iteration": self.iteration,
            "voxel_size": self.voxel_size, "origin": self.origin, "coords": self.coords,
            "params": {k: v.detach() for k, v in self.params.items()},
            "mlps": {r: m.state_dict() for r, m in self.mlps.items()},
            "optimizer": self.opt.state_dict(),
            "stats": {a: getattr(self, a) for a in ("opacity_accum", "anchor_demon", "offset_grad_accum",
                                                    "offset_denom", "life_opacity", "life_views")},
            "np_rng": self.np_rng.bit_generator.state, "torch_gen": self.gen.get_state(),
            "order": list(self.order), "history": self.history, "elapsed": self.elapsed,
            "loss_ema": self.loss_ema, "grown": self.grown, "pruned": self.pruned,
            "rate": None if self.rate_model is None else {
                "model": self.rate_model.state_dict(), "optimizer": self.rate_opt.state_dict(),
                "scales": self.rate_scales()},
        }

    def load_state_dict(self, sd: dict) -> None:
        self.iteration = int(sd["iteration"])
        self.voxel_size = float(sd["voxel_size"])
        self.origin = np.asarray(sd["origin"], np.float32)
        self.coords = sd["coords"].clone()
        c, k = self.cfg.feature_dim, self.cfg.num_offsets
        self.mlps = {"opacity": make_mlp(c, k, "tanh"), "cov": make_mlp(c, 7 * k, "none"),
                     "color": make_mlp(c, 3 * k, "sigmoid")}
        for r, m in self.mlps.items():
            m.load_state_dict(sd["mlps"][r])
        self.params = {k_: nn.Parameter(v.clone()) for k_, v in sd["params"].items()}
        for a, v in sd["stats"].items():
            setattr(self, a, v.clone())
        self.np_rng = np.random.default_rng()
        self.np_rng.bit_generator.state = sd["np_rng"]
        self.gen = torch.Generator()
        self.gen.set_state(sd["torch_gen"])
        self.order = list(sd["order"])
        self.history = list(sd["history"])
        self.elapsed = float(sd["elapsed"])
        self.loss_ema = sd["loss_ema"]
        self.grown, self.pruned = int(sd.get("grown", 0)), int(sd.get("pruned", 0))
        self.build_optimizer()
        self.opt.load_state_dict(sd["optimizer"])
        self.set_lr(self.iteration)
        if sd.get("rate") is not None:
            model_sd = dict(sd["rate"]["model"])
            # the twin's size as saved (the encoder's size rule may have changed since)
            twin_size = None if "twin.table" not in model_sd else (
                model_sd["twin.table"].shape[1], model_sd["twin.feat.0.lin.weight"].shape[0],
                model_sd["twin.head.0.lin.weight"].shape[0])
            self.build_rate_model(sd["rate"]["scales"], twin_size)
            twin = self.rate_model.twin
            if twin is not None and "twin.parent_base" not in model_sd:
                # a checkpoint from before parent_base existed: its twin's mean was parent + o
                model_sd["twin.parent_base"] = torch.ones_like(twin.parent_base)
            self.rate_model.load_state_dict(model_sd)
            self.rate_opt.load_state_dict(sd["rate"]["optimizer"])

    def save_checkpoint(self) -> Path:
        twin = None if self.rate_model is None else self.rate_model.context_twin()
        folder = write_checkpoint_folder(self.to_scene(), self.out, self.iteration, twin)
        buf = io.BytesIO()
        torch.save(self.state_dict(), buf)
        atomic_write_bytes(self.out / STATE_NAME, buf.getvalue())
        self._write_metrics()
        if self.cfg.keep_checkpoints > 0:
            its = sorted(int(d.name.split("_")[1]) for d in (self.out / "point_cloud").glob("iteration_*")
                         if d.name.split("_")[1].isdigit())
            for old in its[:-self.cfg.keep_checkpoints]:
                if old != self.iteration:
                    shutil.rmtree(self.out / "point_cloud" / f"iteration_{old}", ignore_errors=True)
        return folder

    def _write_metrics(self) -> None:
        atomic_write_bytes(self.out / "metrics.json", json.dumps(self.history, indent=1).encode())
        sio = io.StringIO()
        fields = ["iteration", "time_s", "psnr", "ssim", "views", "anchors", "grown", "pruned", "loss_ema",
                  "rate_bits_per_anchor"]
        w = csv.DictWriter(sio, fieldnames=fields, extrasaction="ignore")
        w.writeheader()
        for h in self.history:
            w.writerow(h)
        atomic_write_bytes(self.out / "metrics.csv", sio.getvalue().encode())


def write_checkpoint_folder(scene: AnchorScene, out: Path, iteration: int, twin=None) -> Path:
    """``write_scaffold`` into a temporary sibling of ``out/point_cloud/iteration_<N>``, renamed
    into place once complete (PLY and MLPs, and the rate phase's context twin, ``TWIN_FILE``,
    which lghcc-enc starts its GG-Conv fit from), so a run killed mid-write never leaves an
    iteration folder without its MLPs (readers take the newest ``iteration_<N>``; the hidden
    temporary names do not match). A folder already there for N (a repeated checkpoint) is
    moved aside first and removed after. Leftovers of killed writes are removed."""
    pc = Path(out) / "point_cloud"
    pc.mkdir(parents=True, exist_ok=True)
    for d in pc.iterdir():
        if d.is_dir() and d.name.startswith((TMP_PREFIX, OLD_PREFIX)):
            shutil.rmtree(d, ignore_errors=True)
    name = f"iteration_{iteration}"
    tmp_model = pc / f"{TMP_PREFIX}{name}_{os.getpid()}"
    written = write_scaffold(scene, tmp_model, iteration)  # tmp_model/point_cloud/iteration_<N>
    if twin is not None:
        from ..context.ggconv_train import TWIN_FILE

        twin.save(Path(written) / TWIN_FILE)
    staged = pc / f"{TMP_PREFIX}{name}_{os.getpid()}.ready"
    os.replace(written, staged)
    shutil.rmtree(tmp_model)
    final = pc / name
    old = None
    if final.exists():
        old = pc / f"{OLD_PREFIX}{name}_{os.getpid()}"
        os.replace(final, old)
    os.replace(staged, final)
    _fsync_dir(pc)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
    return final


def _fsync_dir(d: Path) -> None:
    try:
        fd = os.open(d, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def read_train_state(out: str | Path) -> dict:
    """The training state of the run in ``out`` (``STATE_NAME``); InputError naming the file
    when it is missing, unreadable or of another version."""
    sp = Path(out) / STATE_NAME
    if not sp.is_file():
        raise InputError(f"{sp}: no training state to resume from")
    try:
        state = torch.load(sp, map_location="cpu", weights_only=False)
    except Exception as e:
        raise InputError(f"{sp}: cannot load ({e})") from None
    if state.get("version") != STATE_VERSION:
        raise InputError(f"{sp}: training state version {state.get('version')} not supported")
    return state
