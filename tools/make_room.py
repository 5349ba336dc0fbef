#!/usr/bin/env python3
"""Write the procedural room (lghcc.formats.procedural.make_room_scene: a closed 6 x 5 x 3 room with
furniture, watched from inside) as a 3DGS scene, and its capture cameras, the views of a person
standing in it (room_inside_cameras), as an INRIA ``cameras.json`` beside it.

    python tools/make_room.py -o /tmp/room/room.ply --gaussians 60000 --sh-degree 3
    python tools/make_room.py -o /tmp/room_eval/room.ply --camera-seed 7   # other views, to evaluate on

``-o`` takes any name lghcc.formats.write_scene takes (.ply, .spz, .sog, or a folder: a 3DGS model
folder, point_cloud/iteration_0/point_cloud.ply). cameras.json goes in the file's folder, or in the
model folder. Each camera: {id, img_name, width, height, position (the centre), rotation (the
camera-to-world rotation, rows, OpenCV axes: x right, y down, z forward), fx, fy}, as 3DGS writes it.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import argparse  # noqa: E402
import json  # noqa: E402
from pathlib import Path  # noqa: E402

from lghcc.formats import write_scene  # noqa: E402
from lghcc.formats.procedural import make_room_scene, room_inside_cameras  # noqa: E402


def cameras_json(cameras) -> list[dict]:
    """The INRIA cameras.json entries of lghcc Cameras."""
    return [{"id": i, "img_name": c.name, "width": c.width, "height": c.height,
             "position": [float(v) for v in c.center], "rotation": c.camera_to_world[:3, :3].tolist(),
             "fx": c.fx, "fy": c.fy} for i, c in enumerate(cameras)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--output", required=True, help="the scene to write (.ply, .spz, .sog or a folder)")
    ap.add_argument("--gaussians", type=int, default=60_000, help="Gaussians (default 60000, at least 100)")
    ap.add_argument("--sh-degree", type=int, default=0, choices=range(4), help="SH degree (default 0)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the scene and the cameras (default 0)")
    ap.add_argument("--cameras", type=int, default=18, help="inside cameras in cameras.json (default 18)")
    ap.add_argument("--camera-seed", type=int, help="seed of the cameras alone (default: --seed): other views "
                                                    "from the same standing places, to evaluate on views the "
                                                    "encoder never used")
    ap.add_argument("--size", type=int, default=256, help="their image width and height (default 256)")
    args = ap.parse_args(argv)
    if args.gaussians < 100:
        ap.error("--gaussians must be at least 100")
    scene = make_room_scene(args.gaussians, args.sh_degree, args.seed)
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    written = write_scene(scene, out)
    folder = out if written != out else out.parent
    seed = args.seed if args.camera_seed is None else args.camera_seed
    cams = room_inside_cameras(scene, args.cameras, size=args.size, seed=seed)
    (folder / "cameras.json").write_text(json.dumps(cameras_json(cams)) + "\n")
    print(f"wrote {written} ({scene.num_gaussians:,} Gaussians, SH degree {scene.sh_degree}) and "
          f"{folder / 'cameras.json'} ({len(cams)} inside cameras)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
