"""Training a Scaffold-GS anchor scene from posed images on the CPU: lghcc-train (informative).

What it does (Scaffold-GS, Lu et al. 2024, with the differences listed here):

* Data: NeRF-synthetic (``transforms_train.json`` / ``transforms_test.json``), LLFF
  (``poses_bounds.npy`` + ``images/``) or COLMAP (``sparse/0`` + ``images/``), through the
  loaders of ``lghcc.render.camera``. LLFF/COLMAP hold out every 8th image for testing.
* Initialization without SfM points. NeRF-synthetic: random points, uniform inside the
  intersection of the training cameras' view frusta (the region every camera sees; for
  lego a ball of radius ~1.4 around the origin), voxelized on the anchor grid of voxel size
  eps (default: the extent of that region / 64). LLFF/COLMAP: random points on random
  training rays, uniform in inverse depth between the views' near and far bounds
  (``--init sfm`` uses COLMAP's points3D instead when the model has them).
  Anchors: feature 0, offsets 0, log scalings log(mean distance to the 3 nearest anchors)
  (x6), as Scaffold-GS; anchor positions are fixed (Scaffold-GS's position lr is 0).
* Render MLPs (Scaffold-GS): Linear(C+4, C), ReLU, Linear(C, out) with Tanh (opacity, K),
  none (covariance, 7K), Sigmoid (colour, 3K); input [feature, view direction, distance].
* Loss: 0.8 L1 + 0.2 (1 - SSIM) + 0.01 * mean volume of the neural Gaussians (Scaffold-GS's
  scaling regularizer). Adam (eps 1e-15) with Scaffold-GS's learning rates and exponential
  decays; the decays span the whole run (``--iterations``) instead of 30k steps.
* Anchor growing (every ``--densify-interval`` iterations from ``--densify-from`` to
  ``--densify-until``): per neural Gaussian, the mean screen-space gradient norm since the
  last update (Gaussians seen in > 40% of the interval's iterations). At level i = 0..2,
  Gaussians above threshold * 2^i (kept with probability 1 - 0.5^(i+1)) spawn new anchors at
  the centres of voxels of size eps * 16 / 4^i holding no anchor; new anchors take the
  element-wise max of their parents' features, zero offsets and log scalings log(voxel).
  Difference: Scaffold-GS skips the finer levels whenever the coarsest one adds nothing,
  which stops growing once every coarse voxel near the surface holds an anchor (measured on
  lego at 100x100: ~50 anchors grown in 4000 iterations); here every level runs
  (``--skip-finer-levels`` restores the original rule).
  Difference: our rasterizer does not expose the gradient of the 2D means, so the
  screen-space gradient is taken from the gradient of the 3D means: its camera-x/y
  components times z / f (-> pixels) times W/2 (-> NDC, the unit of Scaffold-GS's threshold).
* Anchor pruning (same schedule): anchors seen in > 80% of the interval's iterations whose
  mean summed neural opacity per view is below ``--min-opacity`` are removed (never all).
* Statistics saved with the scene: ``scene.extra["opacity_accum"]`` = mean over the views
  that saw the anchor (since its creation) and over its K offsets of max(0, neural opacity):
  the quantity NAAP (encoder/anchors/naap.py) uses; written as the PLY column ``opacity_accum``.
* Output: ``<out>/point_cloud/iteration_<N>/`` (the Scaffold-GS layout lghcc-enc reads),
  ``<out>/train_state.pth`` (everything needed to resume exactly: parameters, Adam state,
  statistics, RNG states), ``<out>/metrics.json`` / ``metrics.csv`` (test PSNR/SSIM curve),
  ``<out>/config.yaml``. Every file is written atomically, and every iteration folder too (written
  as a hidden sibling, then renamed into place: a killed run never leaves one without MLPs).
* Resume: ``--resume`` continues exactly; with a larger ``--iterations`` it extends the run
  (also a finished one), the learning-rate decays keeping their original span.

Modules: ``config`` (TrainConfig and its checks), ``data`` (initial points, camera extent; the
datasets themselves are lghcc.render.datasets), ``parameters`` (the trainable scene: anchors,
MLPs, Adam and its learning-rate schedules), ``growing`` (anchor growing and pruning, the pruning
after growing), ``losses`` (the image loss and the rate term), ``checkpoints`` (the training
state, checkpoint folders, metrics files), ``evaluation`` (test-view PSNR / SSIM), ``loop``
(``Trainer`` and ``train``); the command line is encoder/train.py.
"""

import os

# Without this, OpenMP threads spin at barriers: on a shared machine (more runnable processes
# than cores) a 2-thread torch run went ~18x slower than 1 thread; passive waiting fixes it.
# Set here, before any module of the package imports torch.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
