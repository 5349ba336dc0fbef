"""Rendering (informative): cameras and loaders, anchors -> neural Gaussians, a
differentiable tile-based CPU rasterizer, image metrics.

Never imports lghcc.encoder (the decoder may render)."""

from .camera import Camera, load_colmap, load_llff, load_nerf_synthetic, read_colmap_model
from .metrics import lpips, psnr, ssim
from .neural_gaussians import NeuralGaussians, SceneTensors, generate_neural_gaussians
from .rasterizer import (RenderResult, gsplat_available, project_gaussians, rasterize, rasterize_gsplat,
                                     render_scene, select_backend)

__all__ = [
    "Camera", "load_colmap", "load_llff", "load_nerf_synthetic", "read_colmap_model",
    "lpips", "psnr", "ssim",
    "NeuralGaussians", "SceneTensors", "generate_neural_gaussians",
    "RenderResult", "gsplat_available", "project_gaussians", "rasterize", "rasterize_gsplat", "render_scene",
    "select_backend",
]
