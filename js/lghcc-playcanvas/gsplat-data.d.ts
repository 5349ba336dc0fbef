// Types of lghcc-playcanvas/gsplat-data (gsplat-data.mjs). Hand-written.
import type { GSplatData } from 'playcanvas';
import type { LghccScene } from 'lghcc-decoder';

/** The per-Gaussian arrays gsplatData() reads: an LghccScene decoded with the default `activated: false`, or a part of one. */
export type LghccSplatArrays = Pick<LghccScene, 'positions' | 'scales' | 'rotations' | 'opacities' | 'colors' | 'sh'>;

/** The engine's splat data (PLY property names, stored 3DGS values) of a scene, or of several parts with one SH degree drawn as one. */
export function gsplatData(scene: LghccSplatArrays | LghccSplatArrays[]): GSplatData;
