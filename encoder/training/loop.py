"""lghcc-train's training loop: ``Trainer`` (one iteration renders one training view: loss,
Adam step, statistics, growing and pruning on their schedule, the start of the rate phase) and
``train`` (a fresh or resumed run with its evaluations, checkpoints, time limit and stop)."""

from __future__ import annotations

import dataclasses
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import yaml

from ...app.fileio import atomic_write_bytes
from ...common.errors import InputError
from ...common.scene import AnchorScene
from ...render.datasets import Dataset, load_dataset, parse_background
from .checkpoints import CheckpointState, read_train_state
from .config import TrainConfig, check_config
from .data import camera_extent
from .evaluation import render_image
from .growing import AnchorGrowing
from .losses import RateTerm, image_loss
from .parameters import AnchorParameters


class Trainer(AnchorParameters, AnchorGrowing, RateTerm, CheckpointState):
    """A Scaffold-GS scene in training on a dataset, writing into ``out``: ``fresh()`` or
    ``load_state_dict()`` starts it, ``step()`` runs one iteration."""

    def __init__(self, cfg: TrainConfig, ds: Dataset, out: Path):
        from ...render.rasterizer import rasterize_with, select_device

        self.cfg, self.ds, self.out = cfg, ds, out
        self.rasterize = rasterize_with(select_device(cfg.device))
        self.bg = torch.as_tensor(parse_background(cfg.background), dtype=torch.float32)
        self.train_images = [torch.from_numpy(np.ascontiguousarray(c.image, np.float32)) for c in ds.train]
        self.spatial_lr_scale = camera_extent(ds.train)
        self.history: list[dict] = []
        self.elapsed = 0.0
        self.loss_ema = None
        self.grown = 0  # anchors added by growing / removed by pruning, since the start
        self.pruned = 0
        self.rate_model = None  # encoder/anchors/rate_model.AnchorRateModel, built when the rate phase starts
        self.rate_opt = None
        self.rate_bits = None  # last estimate of the attribute bits per anchor
        self.prune_report = None  # what prune_anchors did

    # --- one iteration ---------------------------------------------------------------
    def _next_view(self) -> int:
        if not self.order:
            self.order = self.np_rng.permutation(len(self.ds.train)).tolist()
        return self.order.pop()

    def step(self) -> dict:
        """One iteration on the next training view (a random permutation per epoch); growing, pruning
        and the start of the rate phase when their iteration comes. Returns the loss and the number
        of neural Gaussians."""
        from ...render.neural_gaussians import generate_neural_gaussians

        cfg = self.cfg
        it = self.iteration + 1
        self.set_lr(it)
        vi = self._next_view()
        cam, gt = self.ds.train[vi], self.train_images[vi]
        st = self.scene_tensors()
        ng = generate_neural_gaussians(st, cam)
        if ng.num_gaussians == 0:
            # nothing visible: the loss cannot reach any parameter; count the iteration
            self.iteration = it
            return {"loss": float("nan"), "gaussians": 0}
        ng.means.retain_grad()
        res = self.rasterize(ng.means, ng.quats, ng.scales, ng.opacities, ng.colors, cam, background=self.bg)
        loss = self.add_rate_term(image_loss(res.image, gt, ng.scales, cfg))
        loss.backward()
        with torch.no_grad():
            if it > cfg.stats_from and it <= cfg.densify_until:
                self.accumulate_growth_stats(st, ng, cam)
            self.accumulate_lifetime_opacity(ng)
        self.opt.step()
        self.opt.zero_grad(set_to_none=True)
        if self.rate_opt is not None:
            self.rate_opt.step()
            self.rate_opt.zero_grad(set_to_none=True)
        self.iteration = it
        lv = float(loss.detach())
        self.loss_ema = lv if self.loss_ema is None else 0.6 * self.loss_ema + 0.4 * lv
        if (cfg.densify_from < it <= cfg.densify_until and it % cfg.densify_interval == 0):
            self.adjust_anchors()
        if cfg.prune != "none" and it == cfg.prune_iteration:
            self.prune_anchors()
        if cfg.rate_lambda > 0 and self.rate_model is None and it >= cfg.rate_iteration:
            self.build_rate_model()  # the anchor set is final: no growing or pruning after densify_until
        return {"loss": lv, "gaussians": ng.num_gaussians}

    # --- evaluation ------------------------------------------------------------------
    @torch.no_grad()
    def evaluate(self, num_views: int = 0) -> dict:
        from ...render.metrics import psnr, ssim

        test = self.ds.test
        if num_views and num_views < len(test):
            test = [test[i] for i in np.linspace(0, len(test) - 1, num_views).round().astype(int)]
        scene = self.to_scene()
        ps, ss = [], []
        for cam in test:
            img = render_image(scene, cam, self.bg)
            ps.append(psnr(img, cam.image))
            ss.append(ssim(img, cam.image))
        return {"iteration": self.iteration, "time_s": round(self.elapsed, 2), "psnr": float(np.mean(ps)),
                "ssim": float(np.mean(ss)), "views": len(test), "anchors": self.num_anchors,
                "grown": self.grown, "pruned": self.pruned, "loss_ema": self.loss_ema,
                **({} if self.rate_model is None else {"rate_bits_per_anchor": self.rate_estimate()})}


@dataclass
class TrainResult:
    out: Path
    iteration: int
    finished: bool
    history: list
    scene: AnchorScene


def train(cfg: TrainConfig, out: str | Path, *, resume: bool = False, stop_after: int | None = None,
          time_limit_s: float | None = None, progress: bool = True, log=print,
          iterations: int | None = None) -> TrainResult:
    """Train (or resume) into ``out``. ``stop_after``: stop after that iteration with a
    checkpoint, as if interrupted (a later ``resume=True`` continues exactly). ``time_limit_s``:
    stop (with a checkpoint and a full evaluation) once this much training time has passed.
    ``iterations`` (with ``resume``): a new total for the run, also for a finished one, which
    then continues (the learning-rate decays keep their original span; the added iterations
    use the final rates); smaller than the iteration reached raises InputError."""
    out = Path(out)
    state = None
    if resume:
        state = read_train_state(out)
        cfg = _resumed_config(state, cfg, out, iterations, log)
    check_config(cfg)
    torch.set_num_threads(cfg.threads)
    ds = load_dataset(cfg.data, cfg.background, cfg.downscale, cfg.images)
    out.mkdir(parents=True, exist_ok=True)
    tr = _start(cfg, ds, out, state, log)
    bar = None
    if progress:
        from ...app.progress import progress_bar

        bar = progress_bar(total=cfg.iterations, initial=tr.iteration, desc="train", dynamic_ncols=True, file=sys.stderr)
    finished = _iterate(tr, bar, log, stop_after, time_limit_s)
    if bar is not None:
        bar.close()
    if finished and tr.history and tr.history[-1]["iteration"] != tr.iteration:
        tr.history.append(tr.evaluate(0))
        tr.save_checkpoint()
    return TrainResult(out, tr.iteration, finished, tr.history, tr.to_scene())


def _resumed_config(state: dict, cfg: TrainConfig, out: Path, iterations: int | None, log) -> TrainConfig:
    """The saved configuration of the run resumed from ``state``, with ``cfg``'s threads and device
    and, when ``iterations`` is given and differs, that new total (saved in config.yaml)."""
    saved = TrainConfig(**state["config"])
    saved.threads = cfg.threads  # a resumed run may change the threads and extend the iterations
    saved.device = cfg.device
    reached = int(state["iteration"])
    if iterations is not None and iterations != saved.iterations:
        if iterations < reached:
            raise InputError(f"{out}: the run is already at iteration {reached}; --iterations {iterations} "
                             "cannot shorten it")
        if saved.lr_schedule_iterations is None:
            saved.lr_schedule_iterations = saved.iterations
        log(f"run extended from {saved.iterations} to {iterations} iterations (the learning-rate decays keep "
            f"their span of {saved.lr_schedule_iterations}; later iterations use the final rates)")
        saved.iterations = iterations
        atomic_write_bytes(out / "config.yaml",
                           yaml.safe_dump(dataclasses.asdict(saved), sort_keys=False).encode())
    elif reached >= saved.iterations:
        log(f"the run already finished at iteration {reached} of {saved.iterations}; "
            "give --iterations N (> the current count) to continue it")
    return saved


def _start(cfg: TrainConfig, ds: Dataset, out: Path, state: dict | None, log) -> Trainer:
    """The trainer, resumed from ``state`` or started afresh (then config.yaml is written)."""
    tr = Trainer(cfg, ds, out)
    if state is not None:
        tr.load_state_dict(state)
        log(f"resumed at iteration {tr.iteration} ({tr.num_anchors:,} anchors)")
    else:
        tr.fresh()
        atomic_write_bytes(out / "config.yaml", yaml.safe_dump(dataclasses.asdict(cfg), sort_keys=False).encode())
        log(f"{ds.kind}: {len(ds.train)} training / {len(ds.test)} test views of "
            f"{ds.train[0].width}x{ds.train[0].height}; {tr.num_anchors:,} initial anchors, "
            f"voxel size {tr.voxel_size:.5g}, C={cfg.feature_dim}, K={cfg.num_offsets}")
    return tr


def _iterate(tr: Trainer, bar, log, stop_after: int | None, time_limit_s: float | None) -> bool:
    """Train until the last iteration, ``time_limit_s`` of training time or iteration ``stop_after``,
    evaluating and writing checkpoints on their schedule; True when the run reached its last iteration."""
    cfg = tr.cfg
    finished = tr.iteration >= cfg.iterations
    t_start = time.perf_counter() - tr.elapsed
    while tr.iteration < cfg.iterations:
        info = tr.step()
        tr.elapsed = time.perf_counter() - t_start
        it = tr.iteration
        if cfg.prune != "none" and it == cfg.prune_iteration and tr.prune_report:
            (bar.write if bar is not None else log)(f"[it {it}] pruned after growing: {tr.prune_report}")
        if bar is not None:
            _show_progress(bar, tr, info)
        last = it >= cfg.iterations
        timed_out = time_limit_s is not None and tr.elapsed >= time_limit_s
        stop = stop_after is not None and it >= stop_after
        if it % cfg.eval_interval == 0 or last or timed_out:
            t_start += _evaluate_and_report(tr, bar, log, full=last or timed_out)
        if it % cfg.checkpoint_interval == 0 or last or timed_out or stop:
            t0 = time.perf_counter()
            tr.save_checkpoint()
            t_start += time.perf_counter() - t0
        if last:
            finished = True
        if timed_out or stop:
            break
    return finished


def _show_progress(bar, tr: Trainer, info: dict) -> None:
    """One more iteration on the progress bar; every 10th, the loss, anchors and Gaussians."""
    it = tr.iteration
    bar.update(1)
    if it % 10 == 0:
        bar.set_postfix(loss=f"{tr.loss_ema:.4f}" if tr.loss_ema is not None else "-",
                        anchors=tr.num_anchors, gs=info["gaussians"],
                        **({} if tr.rate_bits is None else {"bits_per_anchor": f"{tr.rate_bits:.0f}"}))


def _evaluate_and_report(tr: Trainer, bar, log, full: bool) -> float:
    """Evaluate on the test views (all of them when ``full``, else ``eval_views``), add the record
    to the history and report it; returns the time the evaluation took (not training time)."""
    cfg, it = tr.cfg, tr.iteration
    t0 = time.perf_counter()
    rec = tr.evaluate(0 if full else cfg.eval_views)
    dt = time.perf_counter() - t0  # evaluation time is not training time
    tr.history.append(rec)
    if tr.prune_report and not any(h.get("pruning") for h in tr.history):
        rec["pruning"] = tr.prune_report
    msg = (f"[it {it}] test PSNR {rec['psnr']:.2f} dB, SSIM {rec['ssim']:.4f} ({rec['views']} views), "
           f"{rec['anchors']:,} anchors (+{tr.grown:,} grown, -{tr.pruned:,} pruned so far), {tr.elapsed:.0f} s"
           + (f", ~{rec['rate_bits_per_anchor']:.0f} attribute bits/anchor" if "rate_bits_per_anchor" in rec
              else ""))
    (bar.write(msg) if bar is not None else log(msg))
    return dt
